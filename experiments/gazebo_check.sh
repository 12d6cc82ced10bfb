#!/usr/bin/env bash
# Gazebo Classic 11 check of the exported worlds (not in CI: needs root, debootstrap and about
# 400 MB of Debian packages once). For every preset: export the Gazebo Classic flavour
# (`python -m mjxrow.worlds --gazebo classic`), load it headless with gzserver 11.1 in a Debian
# bullseye chroot, drive the robot open loop at 0.5 m/s straight along its default lane, and
# report load time, errors, real-time factor, when it had driven 20 m and where it ended.
#
#   sudo experiments/gazebo_check.sh [PRESET ...]       (default: all five presets)
#
# Environment: GZ_CHROOT (default /var/tmp/mjxrow-gz-chroot; made on first use with
# `debootstrap --variant=minbase bullseye`), PYTHON (default python3, with mjxrow importable
# from this checkout), COLLISIONS (the exporter's --sdf-collisions, default footprint),
# SPEED (m/s, default 0.5), DISTANCE (m, default 20), PID_P (wheel velocity gain, default 1),
# REUSE=1 (keep the exports of a previous run in the chroot).
#
# Driving: gazebo-plugin-base has no command-line publisher for the skid-steer plugin's
# `vel_cmd` (gz topic cannot publish in Gazebo 11), and `gz joint` commands are not reliably
# delivered, so the check's copy of the robot gets `libJointControlPlugin.so` with a velocity
# target of SPEED / wheel radius on every wheel joint and proportional gain PID_P (Gazebo's
# joint PID is explicit: P · dt / wheel inertia must stay below 2, i.e. P < 3.8 N·m·s/rad for
# the 0.5 kg, 0.098 m sphere wheels at 1 ms; the closed loop's kv = 30 is integrated
# implicitly with armature and would flip the robot here).
#
# Measuring: gzserver runs until the world's simulated time reaches 1.1 · DISTANCE / SPEED,
# recording the robot's pose in a state log (`-r --record_filter robot.pose`); one `gz stats`
# client streams the world statistics for the whole run and is never killed while the server
# runs (gzserver 11.1 aborts with a boost assertion in its transport when a client is killed
# while connected, as polling with `timeout gz ...` does; with `--iters` it did not exit after
# its iterations here). Then gzserver gets SIGINT. Load time = wall time to the first
# statistics line; RTF = the world's simulated / real time over the drive; the end pose and
# the simulated time at which the robot had driven DISTANCE along x come from the state log.
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

if [ "${REUSE:-0}" != 1 ] || [ ! -f "$CHROOT$WORK/${PRESETS[0]}_classic.world" ]; then
  rm -rf "$CHROOT$WORK" && mkdir -p "$CHROOT$WORK"
  echo "exporting ${PRESETS[*]} (gazebo classic, collisions $COLLISIONS) ..." >&2
  for p in "${PRESETS[@]}"; do
    PYTHONPATH="$ROOT${PYTHONPATH:+:$PYTHONPATH}" "$PYTHON" -m mjxrow.worlds --preset "$p" \
      --gazebo classic --sdf-collisions "$COLLISIONS" --out "$CHROOT$WORK" > /dev/null
  done
fi
for p in "${PRESETS[@]}"; do  # the check's drive plugin (see the header)
  model="$CHROOT$WORK/models/${p}_robot_classic/model.sdf"
  r=$(grep -o '<sphere><radius>[0-9.]*' "$model" | head -1 | grep -o '[0-9.]*$')
  target=$(awk -v v="$SPEED" -v r="$r" 'BEGIN{printf "%.4f", v / r}')
  plugin="<plugin name=\"drive\" filename=\"libJointControlPlugin.so\"><controller type=\"velocity\"><joint>.*</joint><target>$target</target><pid_gains>$PID_P 0 0</pid_gains></controller></plugin>"
  sed -i "s|<plugin name=\"skid_steer\" filename=\"libSkidSteerDrivePlugin.so\"/>|$plugin|" "$model"
done

# The driver runs inside the chroot: world file, display number, simulated seconds. Prints
# "load seconds|gzserver exit code|last stats line|state log path".
cat > "$CHROOT$WORK/drive.sh" <<'DRIVER'
#!/bin/bash
set -u
world=$1; disp=$2; tsim=$3
cd "$(dirname "$world")"
name=$(basename "$world" .world)
export HOME=/root GAZEBO_MODEL_PATH="$PWD/models"
rm -rf /root/.gazebo/paging  # Gazebo 11 reuses a cached terrain named "heightmap"
rec="$PWD/rec_$name"; rm -rf "$rec" "$name.stats"; touch "$name.stats"
Xvfb ":$disp" -screen 0 640x480x24 -nolisten tcp > /dev/null 2>&1 & XP=$!
SP=
trap 'kill $XP 2> /dev/null; [ -n "$SP" ] && kill $SP 2> /dev/null' EXIT
sleep 1
t0=$(date +%s.%N)
DISPLAY=":$disp" gzserver --verbose -r --record_path "$rec" --record_filter robot.pose \
  "$world" > "$world.log" 2>&1 & GP=$!
until grep -q 'Connected to gazebo master' "$world.log"; do
  kill -0 "$GP" 2> /dev/null || break; sleep 0.5; done
gz stats -p > "$name.stats" 2> /dev/null & SP=$!
load=
while kill -0 "$GP" 2> /dev/null; do
  last=$(grep -v '^#' "$name.stats" | tail -1)
  if [ -n "$last" ]; then
    [ -n "$load" ] || load=$(awk -v a="$t0" -v b="$(date +%s.%N)" 'BEGIN{printf "%.1f", b - a}')
    [ "$(echo "$last" | awk -F, -v t="$tsim" '{print ($2 + 0 >= t)}')" = 1 ] && break
  fi
  sleep 1
done
kill -INT "$GP" 2> /dev/null
for _ in $(seq 30); do kill -0 "$GP" 2> /dev/null || break; sleep 1; done
kill -9 "$GP" 2> /dev/null; wait "$GP" 2> /dev/null; rc=$?
kill "$SP" 2> /dev/null; SP=
log=$(find "$rec" -name state.log 2> /dev/null | head -1)
echo "$load|$rc|$(grep -v '^#' "$name.stats" | tail -1)|$(grep -v '^#' "$name.stats" | head -1)|$log"
DRIVER
chmod +x "$CHROOT$WORK/drive.sh"

echo "| crop | plants | load [s] | errors (audio device) | RTF | sim time [s] | driven along x [m] | sim time at $DISTANCE m [s] | end x, y, z [m] | end roll, pitch, yaw [rad] | lateral offset [m] |"
echo "|---|---|---|---|---|---|---|---|---|---|---|"
disp=70
tsim=$(awk -v d="$DISTANCE" -v v="$SPEED" 'BEGIN{printf "%.1f", 1.1 * d / v}')
for p in "${PRESETS[@]}"; do
  lanes="$CHROOT$WORK/${p}_lanes.csv"
  read -r x0 y0 < <(awk -F, 'NR == 1 {for (i = 1; i <= NF; i++) c[$i] = i; next}
    $c["default"] == 1 {print $c["spawn_x"], $c["y"]}' "$lanes")
  plants=$(($(wc -l < "$CHROOT$WORK/${p}_plants.csv") - 1))
  # the previous server's master port must be free (TIME-WAIT included)
  for _ in $(seq 120); do ss -tan | grep -q ':11345 ' || break; sleep 1; done
  out=$(chroot "$CHROOT" "$WORK/drive.sh" "$WORK/${p}_classic.world" "$disp" "$tsim" 2>&1 | tail -1)
  disp=$((disp + 1))
  IFS='|' read -r load rc stats first log <<< "$out"
  cp "$CHROOT$WORK/${p}_classic.world.log" "/tmp/gazebo_check_${p}.log" 2> /dev/null || true
  errs=$(grep -c '\[Err\]' "$CHROOT$WORK/${p}_classic.world.log" || true)
  audio=$(grep -c '\[Err\] \[OpenAL' "$CHROOT$WORK/${p}_classic.world.log" || true)
  if [ -z "$log" ] || [ -z "$stats" ]; then
    echo "| $p | $plants | failed: gzserver exit $rc, load ${load:-not finished}, $errs errors (/tmp/gazebo_check_${p}.log) |"
    continue
  fi
  # stats: "rtf [%], sim time, real time, paused"
  read -r sim real < <(echo "$stats" | awk -F, '{print $2 + 0, $3 + 0}')
  read -r sim0 real0 < <(echo "$first" | awk -F, '{print $2 + 0, $3 + 0}')
  rtf=$(awk -v s="$sim" -v r="$real" -v s0="$sim0" -v r0="$real0" \
    'BEGIN{printf "%.2f", (s - s0) / (r - r0)}')
  # the robot's poses with their sim time
  chroot "$CHROOT" gz log -e -r -f "$log" --filter robot.pose --stamp sim 2> /dev/null \
    > "/tmp/gazebo_check_${p}.poses" || true
  read -r x y z roll pitch yaw t20 < <(awk -v x0="$x0" -v d="$DISTANCE" -v tm="$tsim" '
    {n = split($0, f, /[ \t]+/); if (n < 7) next
     t = f[1]; x = f[n - 5]; if (t > tm + 0) exit
     if (t20 == "" && x - x0 >= d) t20 = t
     last = f[n - 5] " " f[n - 4] " " f[n - 3] " " f[n - 2] " " f[n - 1] " " f[n]}
    END {print last, (t20 == "" ? "not reached" : t20)}' "/tmp/gazebo_check_${p}.poses")
  echo "| $p | $plants | $load | $errs ($audio) | $rtf | $tsim |" \
    "$(awk -v x="$x" -v x0="$x0" 'BEGIN{printf "%.2f", x - x0}') | $t20 | $x, $y, $z |" \
    "$roll, $pitch, $yaw | $(awk -v y="$y" -v y0="$y0" 'BEGIN{printf "%+.3f", y - y0}') |"
done
echo "server logs and robot poses: /tmp/gazebo_check_<crop>.log, .poses" >&2
