"""The paper's Table 2 (segmentation accuracy and IoU per crop) beside ours, and a cross-crop
matrix (model trained on one crop, tested on each).

    python experiments/table2_segmentation.py [--data-root DIR] [--n 512] [--out FILE]

Models: the checkpoints `<ckpt-root>/<crop>/` (default the shipped `mjxrow/checkpoints/`), plus
`all/` (one model for every crop) if present. Test sets: with `--data-root`, the test split of
the dataset folder `DIR/<crop>/` (or of `DIR` itself when it holds every crop); without it, `--n`
renders per crop made on the fly with a fixed seed (20,000 + `--seed`), the same for every model.
Pixel accuracy and IoU (plant class, sigmoid > 0.7) are pooled over each test set.

IoU is reported in [0, 1]. The paper's Table 2 (its values as printed, from `mjxrow.crops`;
none for the vineyard) prints IoU figures such as 197.8 and 93.0, which cannot be IoUs in [0, 1]
or in percent; its accuracies lie between 0.63 and 0.80.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pandas as pd

from mjxrow import crops
from mjxrow.files import atomic_write_text, check_out_file
from mjxrow.seg import checkpoint as seg_checkpoint
from mjxrow.seg import evaluation as seg_eval
from paper import cli


def _fmt(x) -> str:
    return "n/a" if x is None or pd.isna(x) else f"{x:.3f}"


def markdown(df: pd.DataFrame, index: str | None = None) -> str:
    """A pipe table of `df` (floats with 3 decimals); `index` names the index column if kept."""
    d = df.reset_index() if index else df
    cols = [index or c if i == 0 and index else c for i, c in enumerate(d.columns)]
    cell = lambda v: _fmt(v) if isinstance(v, float) else str(v)  # noqa: E731
    lines = ["| " + " | ".join(map(str, cols)) + " |", "|" + "---|" * len(cols)]
    lines += ["| " + " | ".join(cell(v) for v in row) + " |" for row in d.itertuples(False)]
    return "\n".join(lines)


def models(root: Path) -> dict[str, Path]:
    """Trained-on name → checkpoint folder, for every crop (and 'all') found under `root`."""
    return {name: root / name for name in (*crops.names(), "all")
            if (root / name / "config.json").is_file()}


def test_counts(module, variables, crop: str, args, size: int) -> pd.DataFrame:
    """Per-image counts of a model on the test set of `crop`."""
    if args.data_root:
        root = Path(args.data_root)
        folder = root / crop if (root / crop / "index.csv").is_file() else root
        return seg_eval.evaluate_folder(module, variables, folder, crop, "test", size, args.batch)
    return seg_eval.evaluate_renders(module, variables, crop, args.n, size, args.batch, args.seed)


def command(argv: list[str] | None = None) -> int:
    """`main` as a command: 0, or 2 with a one-line error (an unknown crop, an output file that
    cannot be written, a damaged checkpoint)."""
    try:
        main(argv)
    except (ValueError, OSError) as e:
        print(f"error: {str(e).splitlines()[0] if str(e) else type(e).__name__}", file=sys.stderr)
        return 2
    return 0


def main(argv: list[str] | None = None) -> tuple[pd.DataFrame, pd.DataFrame]:
    """`python experiments/table2_segmentation.py ARGS` as a function: (table, cross-crop rows),
    printed, and written to `--out` if given."""
    args = cli.table2().parse_args(argv)
    args.ckpt_root = args.ckpt_root or str(seg_checkpoint.CHECKPOINT_DIR)
    args.crops = args.crops or list(crops.names())
    for crop in args.crops:
        crops.get(crop)  # ValueError naming an unknown crop, before any work
    if args.out:
        check_out_file(args.out, "--out")

    found = models(Path(args.ckpt_root))
    if not found:
        raise SystemExit(f"no checkpoints in {args.ckpt_root}: train them with `python -m "
                         "mjxrow.seg.train --crop CROP --on-the-fly --export-to "
                         f"{args.ckpt_root}/CROP`")
    rows, sizes, loaded = [], {}, {}
    for name, path in found.items():
        module, variables = loaded[name] = seg_checkpoint.load(path)
        size = seg_checkpoint.read_config(path)["meta"].get("image_size", 224)
        sizes[name] = size
        for crop in args.crops:
            print(f"model {name} on {crop} ...", file=sys.stderr, flush=True)
            s = seg_eval.summarise(test_counts(module, variables, crop, args, size))
            total = s[(s["crop"] == "all") & (s["condition"] == "all")].iloc[0]
            rows.append({"trained_on": name, "tested_on": crop, "images": int(total["images"]),
                         "accuracy": float(total["accuracy"]), "iou": float(total["iou"])})
    cross = pd.DataFrame(rows)

    table = []
    for crop in args.crops:
        own = crop if crop in found else "all"
        hit = cross[(cross["trained_on"] == own) & (cross["tested_on"] == crop)]
        acc, iou = (hit["accuracy"].iloc[0], hit["iou"].iloc[0]) if len(hit) else (None, None)
        paper = crops.get(crop).paper.get("table2", {})  # Martini et al., Table 2, as printed
        table.append({"crop": crop, "paper accuracy": _fmt(paper.get("accuracy")),
                      "paper IoU": _fmt(paper.get("iou")), "our accuracy": _fmt(acc),
                      "our IoU [0, 1]": _fmt(iou), "model": own if len(hit) else "none",
                      "test images": int(hit["images"].iloc[0]) if len(hit) else 0})
    for row in table:  # the crop's own model at other input sizes
        own = row["model"]
        if own == "none":
            continue
        row["input [px]"] = sizes[own]
        module, variables = loaded[own]
        for size in args.also_sizes:
            print(f"model {own} on {row['crop']} at {size} px ...", file=sys.stderr, flush=True)
            s = seg_eval.summarise(test_counts(module, variables, row["crop"], args, size))
            total = s[(s["crop"] == "all") & (s["condition"] == "all")].iloc[0]
            row[f"IoU at {size} px"] = _fmt(float(total["iou"]))
    table = pd.DataFrame(table)
    matrix = cross.pivot(index="trained_on", columns="tested_on", values="iou")
    matrix = matrix.reindex(index=[n for n in found], columns=args.crops)

    source = (f"test split of {args.data_root}" if args.data_root else
              f"{args.n} renders per crop, seed {20_000 + args.seed}")
    text = ("## Table 2: segmentation per crop\n\n" + markdown(table) +
            f"\n\nTest sets: {source}. IoU in [0, 1]; the paper's columns read n/a for a "
            "crop its Table 2 lacks (see the script's docstring).\n\n"
            "## Cross-crop IoU (rows: trained on, columns: tested on)\n\n" +
            markdown(matrix, "trained on \\ tested on") + "\n")
    print(text)
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(args.out, text)
    return table, cross


if __name__ == "__main__":
    sys.exit(command())
