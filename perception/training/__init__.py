"""Training perception's learned segmenters: what makes the weights a robot cell ships, not part of it.

`learned` trains the EfficientNet-Lite0 segmenter (`python -m shelfpick.perception.training.learned`)
on the renders of `scenes` and of `perception.evaluation.scenes`; `onnx_export` turns its checkpoint
into the ONNX file the runtime runs; `yolo` trains YOLO11n-seg (`shelfpick train-seg`). These need
the `[train]` extra (torch); the runtime in `perception/` never imports this package.
"""
