#!/usr/bin/env bash
# Gazebo Classic 11 check of the exported worlds (not in CI: needs root, debootstrap and about
# 400 MB of Debian packages once). For every preset: export the Gazebo Classic flavour
# (`python -m mjxrow.worlds --gazebo classic`), load it headless with gzserver 11.1 in a Debian
# bullseye chroot, drive the robot open loop at 0.5 m/s straight along its default lane for up
# to 20 m, and report load time, errors, real-time factor and where the robot ended.
#
#   sudo experiments/gazebo_check.sh [PRESET ...]       (default: all five presets)
#
# Environment: GZ_CHROOT (default /var/tmp/mjxrow-gz-chroot; made on first use with
# `debootstrap --variant=minbase bullseye`), PYTHON (default python3, with mjxrow importable
# from this checkout), COLLISIONS (the exporter's --sdf-collisions, default footprint),
# SPEED (m/s, default 0.5), DISTANCE (m, default 20), PID_P (wheel velocity gain, default 1).
#
# Driving: gazebo-plugin-base has no command-line publisher for the skid-steer plugin's
# `vel_cmd` (gz topic cannot publish in Gazebo 11), and `gz joint` commands are not reliably
# delivered, so the check's copy of the robot gets `libJointControlPlugin.so` with a velocity
# target of SPEED / wheel radius on every wheel joint and proportional gain PID_P (Gazebo's
# joint PID is explicit: P · dt / wheel inertia must stay below 2, i.e. P < 3.8 N·m·s/rad for
# the 0.5 kg, 0.098 m sphere wheels at 1 ms; the closed loop's kv = 30 is integrated
# implicitly with armature and would flip the robot here).
set -euo pipefail

ROOT=$(cd "$(dirname "$0")/.." && pwd)
CHROOT=${GZ_CHROOT:-/var/tmp/mjxrow-gz-chroot}
PYTHON=${PYTHON:-python3}
COLLISIONS=${COLLISIONS:-footprint}
SPEED=${SPEED:-0.5}
DISTANCE=${DISTANCE:-20}
PID_P=${PID_P:-1}
PRESETS=("$@")
[ ${#PRESETS[@]} -gt 0 ] || PRESETS=(zucchini lettuce chard pear vineyard)
WORK=/tmp/mjxrow_gz  # inside the chroot

setup() {
  command -v debootstrap > /dev/null || apt-get install -y -q debootstrap
  debootstrap --variant=minbase bullseye "$CHROOT" http://deb.debian.org/debian
  printf '127.0.0.1 localhost\n::1 localhost\n' > "$CHROOT/etc/hosts"
  cp /etc/resolv.conf "$CHROOT/etc/resolv.conf"
  # gazebo 11.1 in bullseye was built against libtar 1.2.20-8+b1; keep that version
  printf 'Package: libtar-dev libtar0\nPin: version 1.2.20-8+b1\nPin-Priority: 1001\n' \
    > "$CHROOT/etc/apt/preferences.d/libtar"
  chroot "$CHROOT" env DEBIAN_FRONTEND=noninteractive bash -c 'apt-get update -q &&
    apt-get install -y -q --no-install-recommends gazebo gazebo-plugin-base xvfb \
      libgl1-mesa-dri procps'
}

MOUNTED=()
cleanup() {
  for ((i = ${#MOUNTED[@]} - 1; i >= 0; i--)); do umount "${MOUNTED[$i]}" || true; done
}
trap cleanup EXIT

[ -x "$CHROOT/usr/bin/gzserver" ] || setup
for d in proc sys dev; do
  if ! mountpoint -q "$CHROOT/$d"; then mount --bind "/$d" "$CHROOT/$d"; MOUNTED+=("$CHROOT/$d"); fi
done

rm -rf "$CHROOT$WORK" && mkdir -p "$CHROOT$WORK"
echo "exporting ${PRESETS[*]} (gazebo classic, collisions $COLLISIONS) ..." >&2
for p in "${PRESETS[@]}"; do
  PYTHONPATH="$ROOT${PYTHONPATH:+:$PYTHONPATH}" "$PYTHON" -m mjxrow.worlds --preset "$p" \
    --gazebo classic --sdf-collisions "$COLLISIONS" --out "$CHROOT$WORK" > /dev/null
done

# The driver runs inside the chroot: world file, start x, lane y, display number.
cat > "$CHROOT$WORK/drive.sh" <<'EOF'
#!/bin/bash
set -u
world=$1; x0=$2; y0=$3; disp=$4; dist=$5; tmax=$6
cd "$(dirname "$world")"
export HOME=/root GAZEBO_MODEL_PATH="$PWD/models"
rm -rf /root/.gazebo/paging  # Gazebo 11 reuses a cached terrain named "heightmap"
Xvfb ":$disp" -screen 0 640x480x24 -nolisten tcp > /dev/null 2>&1 & XP=$!
GP=
stop() { [ -n "$GP" ] && kill "$GP" 2> /dev/null && wait "$GP" 2> /dev/null; kill "$XP" 2> /dev/null; }
trap stop EXIT
sleep 1
t0=$(date +%s.%N)
DISPLAY=":$disp" gzserver --verbose "$world" > "$world.log" 2>&1 & GP=$!
stats() { timeout 5 gz stats -p -d 1 2> /dev/null | grep -v '^#' | tail -1; }
pose() { timeout 5 gz model -m robot -p 2> /dev/null | tail -1; }
s=
while [ -z "$s" ]; do
  kill -0 "$GP" 2> /dev/null || { echo "gzserver exited during load"; exit 1; }
  s=$(stats)
  [ "$(awk -v a="$t0" -v b="$(date +%s.%N)" 'BEGIN{print (b - a > 900)}')" = 1 ] && {
    echo "no world statistics after 900 s"; exit 1; }
done
t1=$(date +%s.%N); sim1=$(echo "$s" | awk -F, '{print $2}')
load=$(awk -v a="$t0" -v b="$t1" -v s="$sim1" 'BEGIN{printf "%.1f", b - a - s}')
p=$(pose); last=$x0; still=0
while :; do
  sleep 2
  p=$(pose); s=$(stats)
  [ -n "$p" ] && [ -n "$s" ] || continue
  sim=$(echo "$s" | awk -F, '{print $2+0}')
  x=$(echo "$p" | awk '{print $1}')
  done=$(awk -v x="$x" -v x0="$x0" -v d="$dist" -v t="$sim" -v tm="$tmax" \
    'BEGIN{print (x - x0 >= d || t >= tm)}')
  moved=$(awk -v x="$x" -v l="$last" 'BEGIN{print (x - l > 0.05)}')
  if [ "$moved" = 1 ]; then still=0; last=$x; else still=$((still + 1)); fi
  [ "$done" = 1 ] || [ "$still" -ge 8 ] && break
done
t2=$(date +%s.%N)
kill "$GP"; wait "$GP" 2> /dev/null; GP=
rtf=$(awk -v a="$t1" -v b="$t2" -v s0="$sim1" -v s1="$sim" 'BEGIN{printf "%.2f", (s1 - s0) / (b - a)}')
errs=$(grep -c '\[Err\]' "$world.log" || true)
audio=$(grep -c '\[Err\] \[OpenAL' "$world.log" || true)
stuck=$([ "$still" -ge 8 ] && echo "stopped" || echo "")
echo "$load $errs $audio $rtf $sim $stuck|$p"
EOF
chmod +x "$CHROOT$WORK/drive.sh"

echo "| crop | plants | load [s] | errors (audio device) | RTF | sim time [s] | driven along x [m] | end x, y, z [m] | end roll, pitch, yaw [rad] | lateral offset [m] |"
echo "|---|---|---|---|---|---|---|---|---|---|"
disp=70
for p in "${PRESETS[@]}"; do
  lanes="$CHROOT$WORK/${p}_lanes.csv"
  read -r x0 y0 < <(awk -F, 'NR == 1 {for (i = 1; i <= NF; i++) c[$i] = i; next}
    $c["default"] == 1 {print $c["spawn_x"], $c["y"]}' "$lanes")
  model="$CHROOT$WORK/models/${p}_robot_classic/model.sdf"
  r=$(grep -o '<sphere><radius>[0-9.]*' "$model" | head -1 | grep -o '[0-9.]*$')
  target=$(awk -v v="$SPEED" -v r="$r" 'BEGIN{printf "%.4f", v / r}')
  plugin="<plugin name=\"drive\" filename=\"libJointControlPlugin.so\"><controller type=\"velocity\"><joint>.*</joint><target>$target</target><pid_gains>$PID_P 0 0</pid_gains></controller></plugin>"
  sed -i "s|<plugin name=\"skid_steer\" filename=\"libSkidSteerDrivePlugin.so\"/>|$plugin|" "$model"
  plants=$(($(wc -l < "$CHROOT$WORK/${p}_plants.csv") - 1))
  tmax=$(awk -v d="$DISTANCE" -v v="$SPEED" 'BEGIN{print 1.5 * d / v}')
  out=$(chroot "$CHROOT" "$WORK/drive.sh" "$WORK/${p}_classic.world" "$x0" "$y0" "$disp" \
        "$DISTANCE" "$tmax" 2>&1 | tail -1)
  disp=$((disp + 1))
  case "$out" in
    *"|"*) ;;
    *) echo "| $p | $plants | failed: $out |"; continue ;;
  esac
  read -r load errs audio rtf sim stuck <<< "${out%%|*}"
  read -r x y z roll pitch yaw <<< "${out##*|}"
  echo "| $p | $plants | $load | $errs ($audio) | $rtf | $sim${stuck:+ ($stuck)} |" \
    "$(awk -v x="$x" -v x0="$x0" 'BEGIN{printf "%.2f", x - x0}') | $x, $y, $z |" \
    "$roll, $pitch, $yaw | $(awk -v y="$y" -v y0="$y0" 'BEGIN{printf "%+.3f", y - y0}') |"
  cp "$CHROOT$WORK/${p}_classic.world.log" "/tmp/gazebo_check_${p}.log" 2> /dev/null || true
done
echo "server logs: /tmp/gazebo_check_<crop>.log" >&2
