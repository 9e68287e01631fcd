"""The appearance front-end: class-agnostic proposals in PV images, ONNX image encoders
(an embedded EfficientNet-lite0 built from registry weights, or any model by path), enrollment
(SVOE / MVPE) and cosine-similarity matching, feeding ``egograph detect``."""
