"""MJX physics: `robot` (the Jackal-like skid-steer UGV and its camera mount), `model` (one
MJX model per static shape, per-world terrain patch and obstacles through model arrays) and `sim`
(state, reset / step, read-outs; re-exports `model`)."""
