"""The paper's Tables 1-3 beside ours: each module computes its table with the library and
prints it (`python experiments/table1.py`, `table2_segmentation.py`, `table3_navigation.py`);
a page is written only where the command is told to (`--out` for Tables 1 and 2, `--doc` for
Table 3: docs/ holds the published pages). `cli` is the commands' light half: their parsers."""
