"""Worlds for other simulators, host only: MuJoCo MJCF with the robot (`mjcf`), Gazebo Sim and
Gazebo Classic SDF (`sdf`, the robot in `gzrobot`), the scene they share (`scene`), the exports
with their CSV ground truth (`export`), and the replay of a sweep's episode (`replay`).
`python -m mjxrow.worlds` is the command (`cli`, its work in `run`)."""
