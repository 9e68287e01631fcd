#!/usr/bin/env python
"""How the device world's PV frames and MVPE photos compare with real HoloLens 2 frames.

Generates two device-world recordings (a lit and a dim room, the same seed), picks still and moving
frames (the head's turn rate over the exposure, synth_gt/device.npz), writes a side-by-side figure
(``--figure``, JPEG) of PV frames and MVPE photos, and prints statistics of every frame at the scale
the real frames are shown at: mean luminance (0-255), sharpness (variance of the Laplacian of the
grey image) against the head's turn rate, and noise (Immerkaer's estimate, grey levels).

The real frames: ``--notebook`` takes the IT3DEgo release's public example notebook
(demo_code/example_projection_between_cameras.ipynb of the IT3DEgo repository); its embedded
matplotlib figures are decoded in memory, the "Raw RGB" / "Raw Target RGB" panels (1280x720 frames
shown at about 327x183 pixels) are cropped out of the figure, and the same statistics are computed
on them. Nothing of the notebook is written anywhere. The generated frames are resized to the
panels' size (area averaging) before the statistics, so both are measured at one scale.

    python tools/synth_realism.py --notebook /path/to/example_projection_between_cameras.ipynb \\
        --figure docs/img/synth_device.jpg --frames 150 --seed 2
"""

from __future__ import annotations

import argparse
import base64
import json
import shutil
import tempfile
from pathlib import Path

import cv2
import numpy as np

from egograph.core.config import load_config
from egograph.core.resources import synth_config
from egograph.synth.config import SynthConfig
from egograph.synth.generate import generate

# The cells of the notebook whose figures show raw PV frames side by side (source starts).
PANEL_CELLS = ("# visualize source and taget frame",)


def spearman(a, b) -> float:
    ra = np.argsort(np.argsort(np.asarray(a, float)))
    rb = np.argsort(np.argsort(np.asarray(b, float)))
    return float(np.corrcoef(ra, rb)[0, 1])


def sharpness(grey: np.ndarray) -> float:
    """Variance of the Laplacian of a grey uint8 image."""
    return float(cv2.Laplacian(grey, cv2.CV_64F).var())


def noise_level(grey: np.ndarray) -> float:
    """Immerkaer's fast noise estimate (std of additive noise, grey levels) of a grey image."""
    m = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float64)
    h, w = grey.shape
    conv = cv2.filter2D(grey.astype(np.float64), -1, m)[1:-1, 1:-1]
    return float(np.sqrt(np.pi / 2) * np.abs(conv).sum() / (6.0 * (w - 2) * (h - 2)))


def stats(rgb: np.ndarray, size: tuple[int, int] | None) -> dict:
    img = rgb if size is None else cv2.resize(rgb, size, interpolation=cv2.INTER_AREA)
    grey = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
    return {"luminance": float(grey.mean()), "sharpness": sharpness(grey), "noise": noise_level(grey)}


def notebook_panels(path: Path) -> list[np.ndarray]:
    """The raw PV panels (RGB uint8) of the figures of the notebook's frame cells."""
    nb = json.loads(path.read_text())
    out = []
    for cell in nb["cells"]:
        src = "".join(cell.get("source", ""))
        if not src.startswith(PANEL_CELLS):
            continue
        for o in cell.get("outputs", []):
            data = o.get("data", {}).get("image/png")
            if not data:
                continue
            fig = cv2.imdecode(np.frombuffer(base64.b64decode(data), np.uint8), cv2.IMREAD_COLOR)[:, :, ::-1]
            w = fig.shape[1]
            for x0, x1 in ((0, w // 2), (w // 2, w)):
                sub = fig[:, x0:x1]
                ink = sub.min(-1) < 235
                rows, cols = np.flatnonzero(ink.mean(1) > 0.6), np.flatnonzero(ink.mean(0) > 0.6)
                out.append(np.ascontiguousarray(sub[rows.min() + 2:rows.max() - 1, cols.min() + 2:cols.max() - 1]))
    if not out:
        raise SystemExit(f"{path}: no cell starting with {PANEL_CELLS} holds a figure")
    return out


def _frames(root: Path) -> tuple[list[Path], dict]:
    meta = json.loads((root / "recording.json").read_text())
    seq = meta["sequence"]
    with np.load(root / "synth_gt" / seq / "device.npz") as d:
        dev = {k: d[k] for k in d}
    return sorted((root / seq / "pv").glob("*.png")), dev


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--notebook", type=Path, help="the IT3DEgo example notebook (real frames)")
    ap.add_argument("--figure", type=Path, help="write the side-by-side figure here (JPEG)")
    ap.add_argument("--config", default=str(synth_config("device-tiny")))
    ap.add_argument("--frames", type=int, default=150)
    ap.add_argument("--seed", type=int, default=2)
    ap.add_argument("--keep", type=Path, help="keep the two recordings under this folder")
    args = ap.parse_args()

    real = notebook_panels(args.notebook) if args.notebook else []
    size = (real[0].shape[1], real[0].shape[0]) if real else (327, 183)
    tmp = Path(tempfile.mkdtemp(prefix="synth_realism_"))
    base = args.keep or tmp
    rows = []
    try:
        recs = {}
        for room, share in (("lit", 0.0), ("dim", 1.0)):
            root = base / room
            if not (root / "recording.json").exists():
                cfg = load_config(SynthConfig, args.config, [f"frames={args.frames}", f"device.light.dim_share={share}",
                                                             "mvpe_photo_size=256"])
                generate(root, cfg, seed=args.seed, progress=True)
            recs[room] = root
        print(f"statistics at {size[0]}x{size[1]} pixels (the notebook's panels)")
        print(f"{'source':<26} {'frames':>6} {'luminance':>10} {'sharpness':>10} {'noise':>7}   (median [min, max])")

        def line(name, ss):
            parts = []
            for key in ("luminance", "sharpness", "noise"):
                v = np.array([s[key] for s in ss])
                parts.append(f"{np.median(v):6.1f} [{v.min():.1f}, {v.max():.1f}]")
            print(f"{name:<26} {len(ss):>6}  " + "  ".join(parts))
            rows.append((name, ss))

        if real:
            line("IT3DEgo notebook (real)", [stats(r, None) for r in real])
        picks = {}
        for room, root in recs.items():
            files, dev = _frames(root)
            rate = dev["pv_exposure_turn_dps"]
            ss = [stats(cv2.imread(str(f))[:, :, ::-1], size) for f in files]
            still = [s for s, r in zip(ss, rate) if r < 10]
            moving = [s for s, r in zip(ss, rate) if r > 100]
            line(f"generated {room}, still", still)
            line(f"generated {room}, moving", moving)
            rho = spearman([s["sharpness"] for s in ss], rate)
            print(f"  {room}: rank correlation of sharpness with the head's turn rate {rho:+.2f} over {len(ss)} frames; "
                  f"exposure {1000 * np.median(dev['pv_exposure_s']):.1f} ms, gain {np.median(dev['pv_gain']):.2f} (medians)")
            order = np.argsort(rate)
            hand = np.flatnonzero(dev["hand_cover"].max(1) > 0.05)
            picks[room] = {"still": files[int(order[0])], "moving": files[int(np.argmin(np.abs(rate - 150.0)))],
                           "hand": files[int(hand[len(hand) // 2])] if len(hand) else files[int(order[len(order) // 2])]}
        if args.figure:
            tiles = []
            for room in ("lit", "dim"):
                row = [cv2.resize(cv2.imread(str(picks[room][k])), (480, 270), interpolation=cv2.INTER_AREA)
                       for k in ("still", "moving", "hand")]
                rates = {k: float(_frames(recs[room])[1]["pv_exposure_turn_dps"][_frames(recs[room])[0].index(picks[room][k])])
                         for k in ("still", "moving", "hand")}
                for img, label in zip(row, (f"still ({rates['still']:.0f} deg/s)", f"moving head ({rates['moving']:.0f} deg/s)",
                                            f"carrying ({rates['hand']:.0f} deg/s)")):
                    cv2.putText(img, f"{room} room, {label}", (8, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 255), 2)
                tiles.append(np.hstack(row))
            seq = json.loads((recs["lit"] / "recording.json").read_text())["sequence"]
            photos = []
            for d in sorted((recs["lit"] / "mvpe" / seq).iterdir())[:3]:
                ims = sorted(d.glob("*.jpg"))
                photos += [cv2.resize(cv2.imread(str(ims[i])), (180, 180)) for i in (0, 12, 24)]
            cv2.putText(photos[0], "MVPE photos", (6, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.55, (255, 255, 255), 2)
            strip = np.hstack(photos[:8])
            strip = cv2.resize(strip, (1440, int(strip.shape[0] * 1440 / strip.shape[1])))
            fig = np.vstack(tiles + [strip])
            args.figure.parent.mkdir(parents=True, exist_ok=True)
            cv2.imwrite(str(args.figure), fig, [cv2.IMWRITE_JPEG_QUALITY, 85])
            print(f"figure: {args.figure} ({fig.shape[1]}x{fig.shape[0]})")
    finally:
        if args.keep is None:
            shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
