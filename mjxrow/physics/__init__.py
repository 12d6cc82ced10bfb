"""MJX physics: `robot` (the Jackal-like skid-steer UGV and its camera mount) and `sim` (one
MJX model per static shape, per-world terrain patch and obstacles through model arrays,
reset / step)."""
