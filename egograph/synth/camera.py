"""The device world's PV camera: scene radiance (linear) -> the pixels the HoloLens 2 photo/video
stream gives after the release's video encoding.

Per frame, in order: auto-exposure that meters the previous frame and follows its target with a lag
(log exposure, first order; exposure time first, then gain, both capped, so a dim room ends up
dark and noisy), vignetting, motion blur integrated over the exposure (per-pixel image motion
from depth and the PV poses at shutter open and close), shot and read noise in electrons amplified
by the gain, the ISP's noise reduction (a Gaussian, wider at a higher gain), sRGB gamma, 8 bits, and a JPEG round trip standing for the video compression.
Linear pixel value at gain 1: ``radiance * sensitivity * exposure_s``.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from egograph.synth.config import PvCameraConfig


@dataclass
class Exposure:
    """What the camera did for one frame: exposure time (s), gain, the metered mean radiance."""

    seconds: float
    gain: float
    metered: float


def _luma(rgb: np.ndarray) -> np.ndarray:
    return rgb @ np.array([0.2126, 0.7152, 0.0722], np.float32)


def metered(radiance: np.ndarray) -> float:
    """Centre-weighted mean luminance of a radiance image (the metering the auto-exposure uses)."""
    h, w = radiance.shape[:2]
    sy, sx = max(1, h // 36), max(1, w // 64)
    small = radiance[sy // 2::sy, sx // 2::sx]   # about 36 x 64 samples
    y = _luma(small)
    yy, xx = np.mgrid[0:small.shape[0], 0:small.shape[1]]
    w = np.exp(-(((xx - (small.shape[1] - 1) / 2) / (0.375 * small.shape[1])) ** 2
                 + ((yy - (small.shape[0] - 1) / 2) / (0.39 * small.shape[0])) ** 2))
    return float((y * w).sum() / w.sum())


class AutoExposure:
    """Lagging auto-exposure: ``step(metered)`` -> the exposure of the next frame."""

    def __init__(self, cfg: PvCameraConfig, fps: float):
        self.cfg = cfg
        self.alpha = 1.0 if cfg.ae_time_constant <= 0 else 1 - np.exp(-1.0 / fps / cfg.ae_time_constant)
        self.log_product = None

    def exposure(self, metered_radiance: float) -> Exposure:
        """Exposure for a frame whose previous frame metered ``metered_radiance``; the first frame
        starts settled."""
        c = self.cfg
        want = np.log(c.ae_target / max(metered_radiance, 1e-6) / c.sensitivity)  # log(seconds * gain)
        if self.log_product is None:
            self.log_product = want
        else:
            self.log_product += self.alpha * (want - self.log_product)
        product = float(np.exp(self.log_product))
        lo, hi = c.exposure_ms[0] / 1000.0, c.exposure_ms[1] / 1000.0
        seconds = float(np.clip(product, lo, hi))
        gain = float(np.clip(product / seconds, 1.0, c.max_gain))
        return Exposure(seconds, gain, metered_radiance)


def vignette(shape: tuple[int, int], strength: float) -> np.ndarray:
    """(H, W, 1) float32 light share falling to ``1 - strength`` in the corners (cos^4-like)."""
    h, w = shape
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    r2 = ((xx - w / 2) ** 2 + (yy - h / 2) ** 2) / ((w / 2) ** 2 + (h / 2) ** 2)
    return (1 - strength * r2 ** 1.5)[:, :, None].astype(np.float32)


def image_motion(depth: np.ndarray, k: np.ndarray, cam_to_world: np.ndarray, open_pose: np.ndarray,
                 close_pose: np.ndarray, step: int = 8) -> np.ndarray:
    """Image motion (H, W, 2) pixels of every pixel between shutter open and close: the pixel's scene
    point (from ``depth``, metres along the view axis, at ``cam_to_world``) projected at the open
    and close poses (row-vector PV poses; camera x right, y up, looking down -z; ``k`` the 3x3
    intrinsics, image y down). Computed on a grid of ``step`` pixels and interpolated."""
    h, w = depth.shape
    d = cv2.resize(depth, (w // step, h // step), interpolation=cv2.INTER_NEAREST).astype(np.float64)
    d = np.minimum(d, 20.0)
    v, u = np.mgrid[0:h // step, 0:w // step].astype(np.float64)
    u, v = (u + 0.5) * step, (v + 0.5) * step
    fx, fy, cx, cy = k[0, 0], k[1, 1], k[0, 2], k[1, 2]
    cam = np.stack([(u - cx) / fx * d, -(v - cy) / fy * d, -d], -1).reshape(-1, 3)
    world = cam @ cam_to_world[:3, :3] + cam_to_world[3, :3]

    def project(pose):
        c = (world - pose[3, :3]) @ pose[:3, :3].T
        z = np.maximum(-c[:, 2], 1e-3)
        return np.stack([c[:, 0] / z * fx + cx, -c[:, 1] / z * fy + cy], 1)

    flow = (project(close_pose) - project(open_pose)).reshape(h // step, w // step, 2).astype(np.float32)
    return cv2.resize(flow, (w, h), interpolation=cv2.INTER_LINEAR)


def motion_blur(img: np.ndarray, flow: np.ndarray, max_taps: int) -> np.ndarray:
    """Average of ``img`` sampled along each pixel's motion path (centred on it): as many taps as the
    longest path has pixels, at most ``max_taps``."""
    longest = float(np.sqrt((flow[::8, ::8] ** 2).sum(-1)).max()) if flow.size else 0.0
    # a tap every 2 pixels of path (bilinear sampling fills between them); a longer path is blurred at
    # a lower resolution, so that taps never lie further apart than 2 pixels (no ghost copies)
    factor = int(np.ceil(longest / (2.0 * max(max_taps - 1, 1))))
    if factor > 1:
        h, w = img.shape[:2]
        small = cv2.resize(img, (w // factor, h // factor), interpolation=cv2.INTER_AREA)
        small_flow = cv2.resize(flow, (w // factor, h // factor), interpolation=cv2.INTER_AREA) / np.float32(factor)
        return cv2.resize(motion_blur(small, small_flow, max_taps), (w, h), interpolation=cv2.INTER_LINEAR)
    taps = int(min(max_taps, np.ceil(longest / 2) + 1))
    if taps < 2:
        return img
    h, w = img.shape[:2]
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    fx, fy = np.ascontiguousarray(flow[:, :, 0]), np.ascontiguousarray(flow[:, :, 1])
    acc = np.zeros_like(img)
    for s in np.linspace(-0.5, 0.5, taps, dtype=np.float32):
        acc += cv2.remap(img, xx + s * fx, yy + s * fy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    acc *= np.float32(1.0 / taps)
    return acc


class NoiseBank:
    """Standard normal noise for whole frames at a small cost per frame: one bank drawn once, a
    frame reads it at a random offset with random signs (drawn from the camera's stream), so
    neighbouring frames do not repeat a pattern."""

    MARGIN = 97

    def __init__(self, rng: np.random.Generator, shape: tuple[int, ...]):
        self.shape = shape
        self.bank = rng.standard_normal((shape[0] + self.MARGIN, shape[1] + self.MARGIN) + tuple(shape[2:]), dtype=np.float32)

    def draw(self, rng: np.random.Generator) -> np.ndarray:
        dy, dx = (int(x) for x in rng.integers(0, self.MARGIN, 2))
        out = self.bank[dy:dy + self.shape[0], dx:dx + self.shape[1]]
        return -out if rng.random() < 0.5 else out


# sRGB-like gamma (value^(1/2.2)) by a table over 12-bit linear values: a power per pixel costs 10x more.
_GAMMA_STEPS = 4096
_GAMMA = (np.power(np.arange(_GAMMA_STEPS) / (_GAMMA_STEPS - 1), 1 / 2.2) * 255.0 + 0.5).astype(np.uint8)


def develop(radiance: np.ndarray, exposure: Exposure, cfg: PvCameraConfig, rng: np.random.Generator,
            vig: np.ndarray | None = None, flow: np.ndarray | None = None, noise: NoiseBank | None = None) -> np.ndarray:
    """RGB uint8 pixels of a radiance image (H, W, 3) exposed as ``exposure``: vignetting, blur along
    ``flow`` (or none), shot + read noise (from ``noise``, or drawn afresh from ``rng``), gain, gamma,
    JPEG round trip."""
    signal = radiance * np.float32(cfg.sensitivity * exposure.seconds)   # linear value at gain 1
    if vig is not None:
        signal *= vig
    if flow is not None:
        signal = motion_blur(signal, flow, cfg.blur_taps)
    np.minimum(signal, np.float32(1.0), out=signal)   # the pixel saturates at full well
    fw = np.float32(cfg.full_well)
    sigma = np.sqrt(signal * fw + np.float32(cfg.read_noise ** 2)) / fw
    z = noise.draw(rng) if noise is not None else rng.standard_normal(signal.shape, dtype=np.float32)
    value = signal + sigma * z
    value *= np.float32(exposure.gain)
    if cfg.denoise_sigma > 0:  # the ISP's spatial noise reduction, stronger at a higher gain (as ISPs do)
        value = cv2.GaussianBlur(value, (0, 0), cfg.denoise_sigma * float(np.sqrt(exposure.gain)))
    np.clip(value, 0.0, 1.0, out=value)
    out = _GAMMA[(value * np.float32(_GAMMA_STEPS - 1) + np.float32(0.5)).astype(np.uint16)]
    if cfg.jpeg_quality:
        ok, buf = cv2.imencode(".jpg", out[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, int(cfg.jpeg_quality)])
        out = cv2.imdecode(buf, cv2.IMREAD_COLOR)[:, :, ::-1]
    return np.ascontiguousarray(out)
