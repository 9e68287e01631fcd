"""Image encoders on onnxruntime: crops of PV frames -> unit embedding vectors.

Any ONNX model with one 4-D image input works; its preprocessing is configuration
(:class:`~egograph.frontend.config.FrontendConfig`: ``input_size``, ``mean``, ``std``, ``layout``,
``output``). The input must be float32 ``(N, 3, S, S)`` (``nchw``) or ``(N, S, S, 3)`` (``nhwc``)
with ``S = input_size`` or a symbolic side; the batch dimension may be fixed at 1 (crops are then
run one by one). The embedding output is ``(N, D)`` or ``(N, T, D)`` (token 0 taken: the class
token of a ViT export such as DINOv2 ViT-S/14: input ``(N, 3, 224, 224)``, output ``(N, 384)``
pooled or ``(N, 257, 384)`` tokens).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from egograph.core.errors import InputError
from egograph.frontend.config import FrontendConfig

DEFAULT_SIDE = 224     # an encoder file with a symbolic input side gets 224 px crops (DINOv2, ImageNet models)
EMBEDDED_SIDE = 224    # the embedded EfficientNet-lite0 at its training side: 160 takes half the time, but
                       # its cosines run lower and MVPE at the 0.6 threshold lost most detections (README)


def as_rgb(image: np.ndarray, order: str = "rgb", what: str = "crop") -> np.ndarray:
    """``image`` as (H, W, 3) uint8 RGB: a grey (H, W) or (H, W, 1) image is repeated over the three
    channels, RGBA / BGRA lose their alpha, ``order`` 'bgr' (OpenCV's) is swapped to RGB. Anything
    else (another dtype, another channel count) raises ValueError naming what it got: an image in
    the wrong colour order or range is never embedded silently wrong."""
    a = np.asarray(image)
    if order not in ("rgb", "bgr"):
        raise ValueError(f"{what}: colour order {order!r}; expected 'rgb' or 'bgr'")
    if a.dtype != np.uint8:
        raise ValueError(f"{what}: dtype {a.dtype}; expected uint8 pixels 0-255 (convert float images with "
                         "np.clip(x * 255, 0, 255).astype(np.uint8))")
    if a.ndim == 3 and a.shape[2] == 1:
        a = a[:, :, 0]
    if a.ndim == 2:
        return np.repeat(a[:, :, None], 3, axis=2)
    if a.ndim != 3 or a.shape[2] not in (3, 4):
        raise ValueError(f"{what}: shape {a.shape}; expected (H, W) grey, (H, W, 3) colour or (H, W, 4) with alpha")
    a = a[:, :, :3]
    return np.ascontiguousarray(a[:, :, ::-1] if order == "bgr" else a)


@dataclass
class Preprocess:
    """How a crop (H, W, 3) uint8 RGB becomes one encoder input: resized to ``size`` x ``size``
    pixels (stretched, or letterboxed with the mean colour), scaled to 0-1, minus ``mean``, over
    ``std``, in ``layout``."""

    size: int = 224
    mean: tuple = (0.485, 0.456, 0.406)
    std: tuple = (0.229, 0.224, 0.225)
    layout: str = "nchw"
    resize: str = "stretch"

    @classmethod
    def from_config(cls, cfg: FrontendConfig) -> "Preprocess":
        return cls(cfg.input_size, tuple(cfg.mean), tuple(cfg.std), cfg.layout, cfg.resize)

    def __call__(self, crops: list[np.ndarray], order: str = "rgb") -> np.ndarray:
        """``crops`` (each converted by :func:`as_rgb`: grey, RGBA, ``order`` 'bgr' made RGB; other
        inputs refused) -> float32 batch (N, 3, S, S) or (N, S, S, 3)."""
        import cv2

        crops = [as_rgb(c, order, f"crop {k}") for k, c in enumerate(crops)]

        s = self.size
        mean = np.asarray(self.mean, np.float32)
        std = np.asarray(self.std, np.float32)
        fill = np.clip(np.round(mean * 255.0), 0, 255).astype(np.uint8)
        resized = np.empty((len(crops), s, s, 3), np.uint8)   # resized in uint8, normalised in one pass
        for k, c in enumerate(crops):
            h, w = c.shape[:2]
            if self.resize == "pad":
                f = s / max(h, w)
                nh, nw = max(1, round(h * f)), max(1, round(w * f))
                r = cv2.resize(c, (nw, nh), interpolation=cv2.INTER_AREA if f < 1 else cv2.INTER_LINEAR)
                resized[k] = fill
                y0, x0 = (s - nh) // 2, (s - nw) // 2
                resized[k, y0:y0 + nh, x0:x0 + nw] = r
            else:
                inter = cv2.INTER_AREA if (h > s or w > s) else cv2.INTER_LINEAR
                resized[k] = cv2.resize(c, (s, s), interpolation=inter)
        out = (resized.astype(np.float32) * np.float32(1 / 255.0) - mean) / std
        return out.transpose(0, 3, 1, 2).copy() if self.layout == "nchw" else out


def _session(path: Path, threads: int, spinning: bool = False):
    """An onnxruntime CPU session with every graph optimisation (the layout transformations of
    ORT_ENABLE_ALL make EfficientNet-lite0 several times faster than ORT_ENABLE_BASIC here) and
    ``threads`` intra-op threads. Without ``spinning`` the idle pool threads sleep instead of
    busy-waiting after each run: spinning threads take the CPU from the proposals and crops that
    run between encoder calls, and from other processes on a shared machine (measured on 2 cores:
    33-44 ms CPU per 224 px crop spinning, 20 ms not)."""
    import onnxruntime as ort

    opts = ort.SessionOptions()
    opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    opts.intra_op_num_threads = threads
    opts.inter_op_num_threads = 1
    opts.add_session_config_entry("session.intra_op.allow_spinning", "1" if spinning else "0")
    opts.log_severity_level = 3
    try:
        return ort.InferenceSession(str(path), sess_options=opts, providers=["CPUExecutionProvider"])
    except Exception as e:  # onnxruntime raises its own exception types for every way a file is bad
        raise InputError(path, f"not a valid ONNX model ({type(e).__name__}: {str(e).splitlines()[0][:200]})") from e


class OnnxEncoder:
    """An ONNX image encoder: :meth:`embed` maps crops to L2-normalised float32 rows (N, D)."""

    def __init__(self, path: str | Path, cfg: FrontendConfig | None = None, preprocess: Preprocess | None = None):
        cfg = cfg or FrontendConfig()
        self.path = Path(path)
        if not self.path.is_file():
            raise InputError(self.path, "encoder file not found (pass --encoder FILE.onnx, or leave frontend.encoder "
                                        "empty for the embedded EfficientNet-lite0)")
        self.pre = preprocess or Preprocess.from_config(cfg)
        self.batch = cfg.batch
        self.session = _session(self.path, cfg.threads, cfg.spinning)
        if self.pre.size == 0:
            self.pre.size = self._model_side()
        self.input_name, self.fixed_batch = self._check_input()
        self.output_name = self._pick_output(cfg.output)
        self.dim = self._probe()

    def _model_side(self) -> int:
        """``frontend.input_size`` 0: the side the model's input fixes, else :data:`DEFAULT_SIDE`."""
        inputs = self.session.get_inputs()
        shape = list(inputs[0].shape) if len(inputs) == 1 else []
        sides = shape[2:4] if self.pre.layout == "nchw" else shape[1:3]
        fixed = [d for d in sides if isinstance(d, int) and d > 0]
        return fixed[0] if len(sides) == 2 and len(fixed) == 2 and fixed[0] == fixed[1] else DEFAULT_SIDE

    def _check_input(self) -> tuple[str, bool]:
        inputs = self.session.get_inputs()
        if len(inputs) != 1:
            raise InputError(self.path, f"an image encoder takes one input; this model takes {len(inputs)} "
                                        f"({', '.join(i.name for i in inputs)})")
        inp = inputs[0]
        s = self.pre.size
        want = ["N", 3, s, s] if self.pre.layout == "nchw" else ["N", s, s, 3]
        shape = list(inp.shape)
        if inp.type != "tensor(float)":
            raise InputError(self.path, f"input {inp.name} is {inp.type}; expected tensor(float) "
                                        f"{want} ({self.pre.layout})")
        ok = len(shape) == 4 and all(not isinstance(d, int) or d == w for d, w in zip(shape[1:], want[1:]))
        if not ok:
            raise InputError(self.path, f"input {inp.name} has shape {shape}; expected {want} ({self.pre.layout}, "
                                        f"frontend.input_size {s}, frontend.layout)")
        return inp.name, isinstance(shape[0], int) and shape[0] == 1

    def _pick_output(self, wanted: str) -> str:
        names = [o.name for o in self.session.get_outputs()]
        if wanted:
            if wanted not in names:
                raise InputError(self.path, f"no output named {wanted!r} (frontend.output); outputs: {', '.join(names)}")
            return wanted
        return "embedding" if "embedding" in names else names[0]

    def _probe(self) -> int:
        """Run one grey crop: checks the model end to end and reads the embedding size."""
        try:
            out = self._run(self.pre([np.full((32, 32, 3), 128, np.uint8)]))
        except InputError:
            raise
        except Exception as e:
            raise InputError(self.path, f"fails on a {self.pre.size} px input ({type(e).__name__}: "
                                        f"{str(e).splitlines()[0][:200]})") from e
        return int(out.shape[1])

    def _run(self, x: np.ndarray) -> np.ndarray:
        y = self.session.run([self.output_name], {self.input_name: x})[0]
        y = np.asarray(y, np.float32)
        if y.ndim == 3:
            y = y[:, 0]     # class token
        elif y.ndim == 4:
            y = y.mean(axis=(2, 3)) if self.pre.layout == "nchw" else y.mean(axis=(1, 2))
        if y.ndim != 2 or y.shape[0] != x.shape[0]:
            raise InputError(self.path, f"output {self.output_name} has shape {list(y.shape)} for a batch of "
                                        f"{x.shape[0]}; expected (N, D) or (N, T, D)")
        return y

    def embed(self, crops: list[np.ndarray], order: str = "rgb") -> np.ndarray:
        """Unit-norm embeddings (N, D) float32 of uint8 crops (any size): RGB, or BGR with ``order``
        'bgr'; grey and RGBA crops are converted, anything else refused (:func:`as_rgb`)."""
        if not crops:
            return np.zeros((0, getattr(self, "dim", 0)), np.float32)
        step = 1 if self.fixed_batch else self.batch
        rows = [self._run(self.pre(crops[k:k + step], order)) for k in range(0, len(crops), step)]
        y = np.concatenate(rows)
        return y / np.maximum(np.linalg.norm(y, axis=1, keepdims=True), 1e-12)

    def run_raw(self, crops: list[np.ndarray], output: str) -> np.ndarray:
        """Another output of the model (e.g. ``logits``) for crops, unnormalised."""
        return np.asarray(self.session.run([output], {self.input_name: self.pre(crops)})[0])


def load_encoder(cfg: FrontendConfig, path: str | Path | None = None) -> OnnxEncoder:
    """The encoder ``path`` (or ``cfg.encoder``), else the embedded EfficientNet-lite0 (which takes
    ImageNet mean and std whatever the knobs say, at ``cfg.input_size``, 0 = :data:`EMBEDDED_SIDE`)."""
    path = path or cfg.encoder
    if path:
        return OnnxEncoder(path, cfg)
    from egograph.frontend import effnet

    pre = Preprocess(cfg.input_size or EMBEDDED_SIDE, effnet.IMAGENET_MEAN, effnet.IMAGENET_STD, "nchw", cfg.resize)
    return OnnxEncoder(effnet.embedded_model_path(), cfg, preprocess=pre)
