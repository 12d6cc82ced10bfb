"""Plant segmenter: MobileNetV3 + LR-ASPP in Flax (`model`), dataset folder loading and
augmentation (`data`), training with resume (`train`), evaluation (`eval`), shipped inference
checkpoints (`checkpoint`) and ONNX export (`export`)."""
