#!/usr/bin/env bash
# Gazebo Classic 11 check of the exported worlds (not in CI: needs root, debootstrap and about
# 400 MB of Debian packages once). For every preset, two parts:
#
# 1. The preset's world: export the Gazebo Classic flavour (`python -m mjxrow.worlds --gazebo
#    classic`), load it headless with gzserver 11.1 in a Debian bullseye chroot, drive the
#    robot open loop at SPEED straight along its default lane, and report load time, errors,
#    real-time factor, when it had driven DISTANCE and where it ended.
# 2. Gazebo against MuJoCo on a flat field (the preset with field.terrain_dh, slope_x, slope_y,
#    stone_density and branch_density 0, no plant collisions, as in MuJoCo's physics): the
#    same open-loop command in both, from the same start pose, (a) straight at SPEED for
#    DISTANCE / SPEED seconds, (b) a 90° turn in place, ω = (π/2) / TURN_S for TURN_S seconds.
#    MuJoCo: experiments/gazebo_mujoco.py (the closed loop's physics in MuJoCo C, stepped as
#    physics.sim.step steps it). Gazebo: the world starts paused, `gz world -m` steps it by
#    exactly the command's duration, and `gz model -p` reads the pose (full precision; the
#    state log keeps 3 significant digits, 0.1 m at x = 30 m). Reported: both end poses, the
#    distance between them (straight; goal ≤ 0.2 m) and the yaw difference (turn; goal ≤ 10°).
#
#   sudo experiments/gazebo_check.sh [PRESET ...]       (default: all five presets)
#
# Environment: GZ_CHROOT (default /var/tmp/mjxrow-gz-chroot; made on first use with
# `debootstrap --variant=minbase bullseye`), PYTHON (default python3, with mjxrow importable
# from this checkout), COLLISIONS (the exporter's --sdf-collisions in part 1, default
# footprint), SPEED (m/s, default 0.5), DISTANCE (m, default 20), TURN_S (s, default 1.6: whole
# MuJoCo control periods), PID_P (wheel velocity gain, default 30 N·m·s/rad: MuJoCo's kv),
# PARTS (default "preset flat"), REUSE=1 (keep the exports of a previous run in the chroot).
#
# Driving: gazebo-plugin-base has no command-line publisher for the skid-steer plugin's
# `vel_cmd` (gz topic cannot publish in Gazebo 11), and `gz joint` commands are not reliably
# delivered, so the check's copy of the robot gets `libJointControlPlugin.so` with a velocity
# target on every wheel joint (SPEED / wheel radius straight; in the turn, MuJoCo's skid-steer
# wheel speeds, `robot.wheel_speeds`, ∓ω·track·turn_factor / 2 / radius) and proportional gain
# PID_P. Gazebo's joint PID is explicit: P · dt / wheel inertia must stay below 2; the exported
# wheels carry MuJoCo's motor armature in their axle inertia (0.052 kg·m², mjxrow.worlds.gzrobot),
# so P = 30 gives 0.58, and the joints' effort limit is MuJoCo's motor torque limit (5 N·m).
#
# Measuring part 1: gzserver runs until the world's simulated time reaches 1.1 · DISTANCE /
# SPEED, recording the robot's pose in a state log (`-r --record_filter robot.pose`); one `gz
# stats` client streams the world statistics for the whole run and is never killed while the
# server runs (gzserver 11.1 aborts with a boost assertion in its transport when a client is
# killed while connected, as polling with `timeout gz ...` does; with `--iters` it did not exit
# after its iterations here). Then gzserver gets SIGINT. Load time = wall time to the first
# statistics line; RTF = the world's simulated / real time over the drive; the end pose and
# the simulated time at which the robot had driven DISTANCE along x come from the state log.
set -euo pipefail

ROOT=$(cd "$(dirname "$0")/.." && pwd)
CHROOT=${GZ_CHROOT:-/var/tmp/mjxrow-gz-chroot}
PYTHON=${PYTHON:-python3}
COLLISIONS=${COLLISIONS:-footprint}
SPEED=${SPEED:-0.5}
DISTANCE=${DISTANCE:-20}
PID_P=${PID_P:-30}
TURN_S=${TURN_S:-1.6}
PARTS=${PARTS:-preset flat}
PRESETS=("$@")
[ ${#PRESETS[@]} -gt 0 ] || PRESETS=(zucchini lettuce chard pear vineyard)
WORK=/tmp/mjxrow_gz  # inside the chroot
FLAT=(--set field.terrain_dh=0 --set field.slope_x=0 --set field.slope_y=0
      --set field.stone_density=0 --set field.branch_density=0)

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
    for c in straight turn; do
      PYTHONPATH="$ROOT${PYTHONPATH:+:$PYTHONPATH}" "$PYTHON" -m mjxrow.worlds --preset "$p" \
        "${FLAT[@]}" --gazebo classic --sdf-collisions none --out "$CHROOT$WORK/flat_$c" \
        > /dev/null
    done
  done
fi

drive_plugin() {  # robot model.sdf, left and right wheel targets [rad/s]: the check's drive
  local ctrl="" side t
  for side in left right; do
    t=$([ $side = left ] && echo "$2" || echo "$3")
    ctrl+="<controller type=\"velocity\"><joint>${side}_.*</joint><target>$t</target><pid_gains>$PID_P 0 0</pid_gains></controller>"
  done
  sed -i "s|<plugin name=\"skid_steer\" filename=\"libSkidSteerDrivePlugin.so\"/>|<plugin name=\"drive\" filename=\"libJointControlPlugin.so\">$ctrl</plugin>|" "$1"
}
radius() { grep -o '<sphere><radius>[0-9.]*' "$1" | head -1 | grep -o '[0-9.]*$'; }
for p in "${PRESETS[@]}"; do
  model="$CHROOT$WORK/models/${p}_robot_classic/model.sdf"
  target=$(awk -v v="$SPEED" -v r="$(radius "$model")" 'BEGIN{printf "%.4f", v / r}')
  drive_plugin "$model" "$target" "$target"
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

disp=70
if [[ " $PARTS " == *" preset "* ]]; then
echo "| crop | plants | load [s] | errors (audio device) | RTF | sim time [s] | driven along x [m] | sim time at $DISTANCE m [s] | end x, y, z [m] | end roll, pitch, yaw [rad] | lateral offset [m] |"
echo "|---|---|---|---|---|---|---|---|---|---|---|"
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
fi
[[ " $PARTS " == *" flat "* ]] || exit 0

# The stepping driver (part 2), inside the chroot: world file, display number, iterations.
# Prints "load seconds|iterations|x y z roll pitch yaw|real seconds of the steps".
cat > "$CHROOT$WORK/step.sh" <<'STEPPER'
#!/bin/bash
set -u
world=$1; disp=$2; iters=$3
cd "$(dirname "$world")"
export HOME=/root GAZEBO_MODEL_PATH="$PWD/models"
rm -rf /root/.gazebo/paging
Xvfb ":$disp" -screen 0 640x480x24 -nolisten tcp > /dev/null 2>&1 & XP=$!
trap 'kill $XP 2> /dev/null' EXIT
sleep 1
t0=$(date +%s.%N)
DISPLAY=":$disp" gzserver --verbose -u "$world" > "$world.log" 2>&1 & GP=$!
until grep -q 'Connected to gazebo master' "$world.log"; do
  kill -0 "$GP" 2> /dev/null || break; sleep 0.5; done
# world statistics from ONE client for the whole run (gz stats prints nothing while the world
# is paused; a client that exits while the server runs can abort it, see the header)
name=$(basename "$world" .world); : > "$name.wstats"
stdbuf -oL gz topic -e /gazebo/default/world_stats -u > "$name.wstats" 2> /dev/null & SP=$!
trap 'kill $XP 2> /dev/null; kill $SP 2> /dev/null' EXIT
stats() {  # "iterations paused" of the latest statistics
  tail -1 "$name.wstats" | sed -n 's/.*paused: \([a-z]*\) iterations: \([0-9]*\).*/\2 \1/p'; }
until [ -n "$(stats)" ]; do kill -0 "$GP" 2> /dev/null || break; sleep 0.5; done
load=$(awk -v a="$t0" -v b="$(date +%s.%N)" 'BEGIN{printf "%.1f", b - a}')
t1=$(date +%s.%N)
for try in 1 2 3; do  # a world-control message sent too early can be lost: resend if unmoved
  gz world -m "$iters" > /dev/null 2>&1
  for _ in $(seq 10); do sleep 0.5; read -r n _ < <(stats); [ "${n:-0}" -gt 0 ] && break; done
  [ "${n:-0}" -gt 0 ] && break
done
while kill -0 "$GP" 2> /dev/null; do
  read -r n paused < <(stats)
  [ "${n:-0}" -ge "$iters" ] && [ "$paused" = true ] && break
  sleep 0.2
done
real=$(awk -v a="$t1" -v b="$(date +%s.%N)" 'BEGIN{printf "%.1f", b - a}')
kill -0 "$GP" 2> /dev/null && pose=$(gz model -m robot -p 2> /dev/null) || pose=
echo "$load|${n:-0}|$pose|$real"
kill -INT "$GP" 2> /dev/null
for _ in $(seq 30); do kill -0 "$GP" 2> /dev/null || break; sleep 1; done
kill -9 "$GP" 2> /dev/null; wait "$GP" 2> /dev/null
kill "$SP" 2> /dev/null
STEPPER
chmod +x "$CHROOT$WORK/step.sh"

omega=$(awk -v t="$TURN_S" 'BEGIN{printf "%.6f", 3.14159265358979 / 2 / t}')
tstraight=$(awk -v d="$DISTANCE" -v v="$SPEED" 'BEGIN{print d / v}')
echo
echo "Flat field, the same open-loop command in Gazebo Classic and MuJoCo (positions: forward, left of the start [m]; yaw: change [°]):"
echo
echo "| crop | straight $DISTANCE m: MuJoCo end | Gazebo end | Δ end position [m] | Gazebo RTF | turn 90°: MuJoCo yaw | Gazebo yaw | Δ yaw [°] | Gazebo turn end position Δ [m] |"
echo "|---|---|---|---|---|---|---|---|---|"
for p in "${PRESETS[@]}"; do
  res=()
  for c in straight turn; do
    if [ "$c" = straight ]; then cmd=("$SPEED" 0); secs=$tstraight; else cmd=(0 "$omega"); secs=$TURN_S; fi
    mj=$(PYTHONPATH="$ROOT${PYTHONPATH:+:$PYTHONPATH}" "$PYTHON" "$ROOT/experiments/gazebo_mujoco.py" \
      --preset "$p" "${FLAT[@]}" --cmd "${cmd[@]}" --seconds "$secs" 2> /dev/null | tail -1)
    dir="$CHROOT$WORK/flat_$c"
    model="$dir/models/${p}_robot_classic/model.sdf"
    if grep -q 'libSkidSteerDrivePlugin' "$model"; then
      read -r wl wr < <(echo "$mj" | "$PYTHON" -c 'import json, sys
w = json.load(sys.stdin)["wheel_speeds"]; print(f"{w[0]:.4f} {w[1]:.4f}")')
      drive_plugin "$model" "$wl" "$wr"
    fi
    dt=$(grep -o '<max_step_size>[0-9.]*' "$dir/${p}_classic.world" | grep -o '[0-9.]*$')
    iters=$(awk -v s="$secs" -v dt="$dt" 'BEGIN{printf "%d", s / dt + 0.5}')
    for _ in $(seq 120); do ss -tan | grep -q ':11345 ' || break; sleep 1; done
    gz=$(chroot "$CHROOT" "$WORK/step.sh" "$WORK/flat_$c/${p}_classic.world" "$disp" "$iters" \
      2>&1 | tail -1)
    disp=$((disp + 1))
    cp "$dir/${p}_classic.world.log" "/tmp/gazebo_check_flat_${c}_${p}.log" 2> /dev/null || true
    res+=("$("$PYTHON" - "$mj" "$gz" "$dir/${p}_lanes.csv" "$secs" <<'CMP'
import csv, json, math, sys
mj, gz, lanes, secs = json.loads(sys.argv[1]), sys.argv[2].split("|"), sys.argv[3], float(sys.argv[4])
spawn = next(r for r in csv.DictReader(open(lanes)) if r["default"] == "1")
x0, y0, yaw0 = (float(spawn[k]) for k in ("spawn_x", "spawn_y", "spawn_yaw"))
m = mj["at"][-1]["pose"]
try:
    g = [float(v) for v in gz[2].split()]
    assert len(g) == 6
except (AssertionError, IndexError, ValueError):
    print(f"failed: gazebo {'|'.join(gz)!r}|failed|-|-|-"); sys.exit()
def rel(p):
    dx, dy = p[0] - x0, p[1] - y0
    c, s = math.cos(yaw0), math.sin(yaw0)
    return c * dx + s * dy, -s * dx + c * dy, math.degrees(math.remainder(p[5] - yaw0, math.tau))
(mf, ml, my), (gf, gl, gy) = rel(m), rel(g)
dpos = math.hypot(g[0] - m[0], g[1] - m[1])
dyaw = math.degrees(math.remainder(g[5] - m[5], math.tau))
rtf = secs / float(gz[3]) if gz[3] else float("nan")
print(f"{mf:.3f}, {ml:+.3f}, {my:+.1f}°|{gf:.3f}, {gl:+.3f}, {gy:+.1f}°|{dpos:.3f}|{rtf:.2f}|{dyaw:+.1f}")
CMP
)")
  done
  IFS='|' read -r s_mj s_gz s_d s_rtf _ <<< "${res[0]}"
  IFS='|' read -r t_mj t_gz t_d _ t_dyaw <<< "${res[1]}"
  echo "| $p | $s_mj | $s_gz | $s_d | $s_rtf | ${t_mj##*, } | ${t_gz##*, } | $t_dyaw | $t_d |"
done
echo "server logs: /tmp/gazebo_check_flat_<straight|turn>_<crop>.log" >&2
