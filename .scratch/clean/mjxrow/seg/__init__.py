"""Plant segmenter: MobileNetV3 + LR-ASPP in Flax (`model`), dataset folder loading and
augmentation (`data`), the synthetic dataset (`synthesis`), training with resume (`training`),
evaluation (`evaluation`), shipped inference checkpoints (`checkpoint`) and ONNX export
(`onnx_export`). The commands `python -m mjxrow.seg.synth`, `.train`, `.eval` and `.export` are
the light modules of those names (mjxrow.commands), each handing over to its heavy module."""
