"""The paper's Tables 1-3 beside ours: each module computes its table with the library and
writes it into `docs/` (`python experiments/table1.py`, `table2_segmentation.py`,
`table3_navigation.py`)."""
