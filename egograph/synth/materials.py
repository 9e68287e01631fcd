"""Photographic surfaces of the device world: textures built from freely licensed photographs that
ship inside registry packages, read from the installed package at run time (nothing is copied into
egograph, nothing is downloaded).

Sources (package, file in the package, licence as the package states it):

* scikit-image (``skimage/data``): astronaut.png (NASA, public domain), coffee.png (CC0, Rachel
  Michetti), chelsea.png (CC0, Stefan van der Walt), rocket.jpg (SpaceX, public domain),
  hubble_deep_field.jpg (NASA, public domain), camera.png (CC0, Lav Varshney), text.png (public
  domain), brick.png, grass.png, gravel.png (CC0Textures, CC0); the notices are in the docstrings of
  ``skimage.data``.
* scikit-learn (``sklearn/datasets/images``): china.jpg and flower.jpg, CC BY 2.0, attribution in
  ``sklearn/datasets/images/README.txt`` (danielbuechele, vultilion on Flickr).

:func:`photo_sources` names the package versions a recording was built with (recording.json).

Textures are sRGB uint8 images (H, W, 3), row 0 at v = 0. Every product texture is
``TEXTURE_SIZE`` square; its bottom rows (v >= ``PLAIN_V``) hold plain materials that caps, rims,
insides, spines, page edges and leaves map into (:data:`PLAIN_UV`), the rows above the print.
"""

from __future__ import annotations

import colorsys
import importlib.metadata
import importlib.util
from dataclasses import dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np

from egograph.core.errors import ConfigError

TEXTURE_SIZE = 512
PLAIN_V = 0.875          # rows from here down hold the plain materials
PRINT_ROWS = int(TEXTURE_SIZE * PLAIN_V)
# uv of the plain materials in the strip: four cells across (cap/rim, inside/bottom, page edge, leaf)
PLAIN_UV = {"cap": (0.125, 0.94), "inside": (0.375, 0.94), "pages": (0.625, 0.94), "leaf": (0.875, 0.94)}

# name -> (package, path in the package, licence)
PHOTOS = {
    "astronaut": ("scikit-image", "skimage/data/astronaut.png", "public domain (NASA)"),
    "coffee": ("scikit-image", "skimage/data/coffee.png", "CC0 (Rachel Michetti)"),
    "chelsea": ("scikit-image", "skimage/data/chelsea.png", "CC0 (Stefan van der Walt)"),
    "rocket": ("scikit-image", "skimage/data/rocket.jpg", "public domain (SpaceX)"),
    "hubble": ("scikit-image", "skimage/data/hubble_deep_field.jpg", "public domain (NASA)"),
    "camera": ("scikit-image", "skimage/data/camera.png", "CC0 (Lav Varshney)"),
    "text": ("scikit-image", "skimage/data/text.png", "public domain"),
    "brick": ("scikit-image", "skimage/data/brick.png", "CC0 (CC0Textures)"),
    "grass": ("scikit-image", "skimage/data/grass.png", "CC0 (CC0Textures)"),
    "gravel": ("scikit-image", "skimage/data/gravel.png", "CC0 (CC0Textures)"),
    "china": ("scikit-learn", "sklearn/datasets/images/china.jpg", "CC BY 2.0 (danielbuechele, Flickr)"),
    "flower": ("scikit-learn", "sklearn/datasets/images/flower.jpg", "CC BY 2.0 (vultilion, Flickr)"),
}
COLOUR_PHOTOS = ("astronaut", "coffee", "chelsea", "rocket", "hubble", "china", "flower")
_MODULE = {"scikit-image": "skimage", "scikit-learn": "sklearn"}


def _site(package: str) -> Path | None:
    spec = importlib.util.find_spec(_MODULE[package])
    return None if spec is None or spec.origin is None else Path(spec.origin).parent.parent


class PhotoLibrary:
    """The source photographs, read once from the installed packages (sRGB uint8, RGB or grey)."""

    def __init__(self):
        self.images: dict[str, np.ndarray] = {}
        tried = []
        for name, (package, rel, _) in PHOTOS.items():
            site = _site(package)
            path = None if site is None else site / rel
            img = None if path is None else cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
            if img is None:
                tried.append(f"{rel} of {package}" + ("" if site else " (package not installed)"))
                continue
            if img.ndim == 3:
                img = cv2.cvtColor(img[:, :, :3], cv2.COLOR_BGR2RGB)
            self.images[name] = img
        if tried:
            raise ConfigError("world=device needs the photographs shipped in scikit-image and scikit-learn; not found: "
                              + "; ".join(tried) + " (pip install scikit-image scikit-learn)")

    def rgb(self, name: str) -> np.ndarray:
        img = self.images[name]
        return img if img.ndim == 3 else np.repeat(img[:, :, None], 3, 2)

    def crop(self, name: str, box: tuple[float, float, float, float], shape: tuple[int, int]) -> np.ndarray:
        """Crop ``box`` (x0, y0, x1, y1 as shares of the photo) resized to ``shape`` (rows, cols), RGB uint8."""
        img = self.rgb(name)
        h, w = img.shape[:2]
        x0, y0, x1, y1 = int(box[0] * w), int(box[1] * h), max(int(box[2] * w), int(box[0] * w) + 2), \
            max(int(box[3] * h), int(box[1] * h) + 2)
        return cv2.resize(img[y0:y1, x0:x1], (shape[1], shape[0]), interpolation=cv2.INTER_AREA)


def photo_sources() -> dict[str, str]:
    """Package -> installed version of the packages the photographs come from."""
    return {p: importlib.metadata.version(p) for p in sorted({v[0] for v in PHOTOS.values()})}


# ---------------------------------------------------------------- colour helpers

def _hsv(h: float, s: float, v: float) -> np.ndarray:
    return np.array(colorsys.hsv_to_rgb(h % 1.0, s, v)) * 255.0


def turn_hue(img: np.ndarray, degrees: float) -> np.ndarray:
    """The image (RGB uint8) with its hue turned by ``degrees``."""
    if not degrees:
        return img
    hsv = cv2.cvtColor(img, cv2.COLOR_RGB2HSV_FULL).astype(np.int32)
    hsv[:, :, 0] = (hsv[:, :, 0] + int(round(degrees / 360.0 * 256))) % 256
    return cv2.cvtColor(hsv.astype(np.uint8), cv2.COLOR_HSV2RGB_FULL)


def _noise(rng: np.random.Generator, shape: tuple[int, int], scale: int) -> np.ndarray:
    """Smooth noise in [-1, 1] (rows, cols): random values on a coarse grid, cubic upsampled."""
    small = rng.uniform(-1, 1, (max(2, shape[0] // scale), max(2, shape[1] // scale))).astype(np.float32)
    return np.clip(cv2.resize(small, (shape[1], shape[0]), interpolation=cv2.INTER_CUBIC), -1, 1)


def _blend(dst: np.ndarray, src: np.ndarray, y: int, x: int, mask: np.ndarray | None = None) -> None:
    h, w = src.shape[:2]
    region = dst[y:y + h, x:x + w]
    h, w = region.shape[:2]
    if mask is None:
        region[:] = src[:h, :w]
    else:
        m = mask[:h, :w, None].astype(np.float32)
        region[:] = (region * (1 - m) + src[:h, :w] * m).astype(np.uint8)


# ---------------------------------------------------------------- designs

@dataclass
class Design:
    """What a product's print is made of; a look-alike twin is the same design with one change."""

    category: str
    material: np.ndarray            # (3,) sRGB 0-255 body colour (glaze, plastic, cardboard, cover)
    accent: np.ndarray              # (3,) sRGB 0-255 print colour
    photo: str                      # photograph on the label
    crop: tuple[float, float, float, float]
    layout: int                     # 0 band label, 1 panel, 2 all-over photo, 3 stripes and motif
    seed: int                       # procedural print details (text lines, stripes, speckle)
    hue: float = 0.0                # degrees the whole print is turned (a colour twin)
    sticker: tuple | None = None    # (u, v, side as share of the print height, photo, crop): a small region replaced
    cap: np.ndarray = field(default_factory=lambda: np.array([200.0, 200.0, 200.0]))


def random_design(rng: np.random.Generator, category: str) -> Design:
    photo = str(rng.choice(COLOUR_PHOTOS))
    w = rng.uniform(0.25, 0.6)
    x0, y0 = rng.uniform(0, 1 - w), rng.uniform(0, 1 - w)
    hue = rng.random()
    mat = {"mug": _hsv(hue, rng.uniform(0.1, 0.7), rng.uniform(0.5, 0.95)),
           "bowl": _hsv(hue, rng.uniform(0.05, 0.5), rng.uniform(0.6, 0.95)),
           "remote": _hsv(hue, 0.1, rng.uniform(0.1, 0.25)),
           "book": _hsv(hue, rng.uniform(0.3, 0.8), rng.uniform(0.3, 0.85)),
           "box": _hsv(hue, rng.uniform(0.4, 0.9), rng.uniform(0.5, 0.95))}.get(
        category, _hsv(hue, rng.uniform(0.3, 0.9), rng.uniform(0.4, 0.95)))
    accent = _hsv(hue + rng.uniform(0.3, 0.7), rng.uniform(0.5, 1.0), rng.uniform(0.2, 0.95))
    layout = {"can": int(rng.choice([0, 2, 3])), "bottle": 0, "box": int(rng.choice([1, 2])), "book": int(rng.choice([1, 2])),
              "mug": int(rng.choice([1, 3])), "bowl": 3, "remote": 3, "toy": 2, "plant": 3}.get(category, 1)
    cap = _hsv(rng.random(), rng.uniform(0, 0.6), rng.uniform(0.3, 0.95))
    return Design(category, mat, accent, photo, (x0, y0, x0 + w, y0 + w * rng.uniform(0.6, 1.2)), layout,
                  int(rng.integers(2**31)), cap=cap)


def twin_design(rng: np.random.Generator, first: Design, kind: str, hue_range: tuple[float, float],
                sticker_size: float) -> Design:
    """The look-alike of ``first``: ``label`` another photograph and crop on the same layout and colours,
    ``colour`` the same print with its hue turned, ``sticker`` the same print with one small region replaced."""
    if kind == "colour":
        return replace(first, hue=float(rng.uniform(*hue_range)) * float(rng.choice([-1, 1])))
    if kind == "label":
        other = str(rng.choice([p for p in COLOUR_PHOTOS if p != first.photo]))
        w = rng.uniform(0.25, 0.6)
        x0, y0 = rng.uniform(0, 1 - w), rng.uniform(0, 1 - w)
        return replace(first, photo=other, crop=(x0, y0, x0 + w, y0 + w))
    photo = str(rng.choice(COLOUR_PHOTOS))
    c0 = rng.uniform(0, 0.7, 2)
    # On the label's front half (u in [0.05, 0.4]) where a wearer facing the print sees it.
    return replace(first, sticker=(float(rng.uniform(0.05, 0.4)), float(rng.uniform(0.2, 0.6)), sticker_size, photo,
                                   (c0[0], c0[1], c0[0] + 0.3, c0[1] + 0.3)))


def _text_lines(lib: PhotoLibrary, rng: np.random.Generator, shape: tuple[int, int], ink: np.ndarray,
                paper: np.ndarray) -> np.ndarray:
    """Lines of printed text: crops of the public-domain text photo thresholded to ink."""
    src = lib.images["text"] if lib.images["text"].ndim == 2 else cv2.cvtColor(lib.images["text"], cv2.COLOR_RGB2GRAY)
    h, w = src.shape
    y0 = int(rng.integers(0, max(1, h - 40)))
    x0 = int(rng.integers(0, max(1, w - 150)))
    piece = cv2.resize(src[y0:y0 + 40, x0:x0 + 150], (shape[1], shape[0]), interpolation=cv2.INTER_AREA)
    ink_share = np.clip((110.0 - piece.astype(np.float32)) / 60.0, 0, 1)[:, :, None]
    return (paper * (1 - ink_share) + ink * ink_share).astype(np.uint8)


def _put_text(img: np.ndarray, lib: PhotoLibrary, rng: np.random.Generator, where: tuple[int, int, int, int],
              ink: np.ndarray, paper: np.ndarray) -> None:
    y0, y1, x0, x1 = where
    img[y0:y1, x0:x1] = _text_lines(lib, rng, (y1 - y0, x1 - x0), ink, paper)


def render_design(lib: PhotoLibrary, d: Design) -> np.ndarray:
    """The product texture (TEXTURE_SIZE square, sRGB uint8) of a design."""
    rng = np.random.default_rng(d.seed)
    n = TEXTURE_SIZE
    img = np.empty((n, n, 3), np.float32)
    img[:] = d.material
    # Material grain: ceramic speckle, cardboard fibres, plastic sheen variation.
    grain = lib.images["gravel"].astype(np.float32)
    grain = cv2.resize(grain, (n, n))[:, :, None] / 255.0 - 0.5
    img *= 1.0 + (0.12 if d.category in ("box", "book") else 0.05) * grain
    img *= 1.0 + 0.04 * _noise(rng, (n, n), 64)[:, :, None]
    p = PRINT_ROWS
    if d.layout == 0:      # a band label round the middle: photo, name text, stripes
        top, bottom = int(p * 0.28), int(p * 0.78)
        img[top:bottom] = d.accent
        ph = bottom - top
        _blend(img, lib.crop(d.photo, d.crop, (int(ph * 0.62), int(n * 0.45))).astype(np.float32), top + int(ph * 0.3), int(n * 0.05))
        img[top:top + 10] = d.material * 0.4
        img[bottom - 10:bottom] = d.material * 0.4
        _put_text(img, lib, rng, (top + 14, top + int(ph * 0.26), int(n * 0.05), int(n * 0.5)), d.material * 0.2, d.accent)
    elif d.layout == 1:    # a photo panel on the front, title and small print
        ph, pw = int(p * 0.5), int(n * 0.42)
        _blend(img, lib.crop(d.photo, d.crop, (ph, pw)).astype(np.float32), int(p * 0.3), int(n * 0.04))
        _put_text(img, lib, rng, (int(p * 0.08), int(p * 0.22), int(n * 0.04), int(n * 0.46)), d.accent, d.material)
        _put_text(img, lib, rng, (int(p * 0.86), int(p * 0.95), int(n * 0.04), int(n * 0.46)), d.accent * 0.6, d.material)
        img[:, int(n * 0.52):int(n * 0.55)] = d.accent
    elif d.layout == 2:    # the photograph all over (a can wrap, a plush toy, a cover)
        img[:p] = lib.crop(d.photo, d.crop, (p, n)).astype(np.float32)
        _put_text(img, lib, rng, (int(p * 0.05), int(p * 0.16), int(n * 0.05), int(n * 0.45)), d.material * 0.3, d.accent)
    else:                  # stripes and a motif
        period = int(rng.integers(24, 64))
        yy = np.arange(p)[:, None]
        stripe = ((yy // period) % 2 == 0) & (yy < p * 0.3)
        img[:p][np.broadcast_to(stripe, (p, n))] = d.accent
        r = int(p * 0.2)
        mask = np.zeros((2 * r, 2 * r), np.float32)
        cv2.circle(mask, (r, r), r - 2, 1.0, -1, lineType=cv2.LINE_AA)
        for cx in (int(n * 0.2), int(n * 0.7)):
            _blend(img, lib.crop(d.photo, d.crop, (2 * r, 2 * r)).astype(np.float32), int(p * 0.45), cx - r, mask)
    if d.category == "remote":  # a keypad of round buttons
        for row in range(6):
            for col in range(3):
                c = d.accent if (row + col) % 4 == 0 else d.material * 1.8 + 30
                cv2.circle(img, (int(n * (0.2 + 0.15 * col)), int(p * (0.15 + 0.12 * row))), 14, tuple(float(x) for x in c), -1,
                           lineType=cv2.LINE_AA)
    # The plain strip: cap/rim, inside/bottom, page edges, leaves.
    q = n // 4
    img[p:, 0:q] = d.cap
    img[p:, q:2 * q] = np.clip(d.material * 1.1 + 20, 0, 255)
    pages = 235 - 25 * ((np.arange(n - p)[:, None] // 2) % 2)
    img[p:, 2 * q:3 * q] = pages[:, :, None]
    leaf = cv2.resize(lib.rgb("grass"), (q, n - p)).astype(np.float32) / 255.0
    img[p:, 3 * q:] = leaf * np.array([60.0, 140.0, 40.0]) + 20
    out = np.clip(img, 0, 255).astype(np.uint8)
    if d.hue:
        out[:p] = turn_hue(out[:p], d.hue)
    if d.sticker is not None:
        u, v, side, photo, crop = d.sticker
        s = max(8, int(side * p))
        y, x = int(v * p), int(u * n)
        mask = np.zeros((s, s), np.float32)
        cv2.circle(mask, (s // 2, s // 2), s // 2 - 1, 1.0, -1, lineType=cv2.LINE_AA)
        _blend(out, lib.crop(photo, crop, (s, s)), y, x, mask)
    return out


# ---------------------------------------------------------------- room materials

def wood_texture(rng: np.random.Generator, lib: PhotoLibrary, tone: float) -> np.ndarray:
    """Planks of wood: grain rings warped by smooth noise, a photographic fibre detail (gravel,
    stretched), planks of slightly different tones; ``tone`` in [0, 1] light oak -> walnut."""
    n = TEXTURE_SIZE
    yy, xx = np.mgrid[0:n, 0:n].astype(np.float32)
    warp = _noise(rng, (n, n), 96) * 18 + _noise(rng, (n, n), 24) * 3
    rings = 0.5 + 0.5 * np.sin((yy + warp) * 0.35 + 3 * _noise(rng, (n, n), 128))
    fibre = cv2.resize(lib.images["gravel"].astype(np.float32), (n * 4, n // 4))[:, :n]
    fibre = cv2.resize(fibre, (n, n)) / 255.0 - 0.5
    light, dark = np.array([200, 160, 115]) * (1 - 0.55 * tone), np.array([150, 105, 65]) * (1 - 0.55 * tone)
    img = dark + (light - dark) * (0.6 * rings + 0.4 * (fibre + 0.5))[:, :, None]
    plank = (yy // (n // 4)).astype(int)
    img *= (1 + 0.08 * rng.uniform(-1, 1, 4)[plank])[:, :, None]
    img[(yy.astype(int) % (n // 4)) < 2] *= 0.55
    return np.clip(img, 0, 255).astype(np.uint8)


def plaster_texture(rng: np.random.Generator, lib: PhotoLibrary, colour: np.ndarray) -> np.ndarray:
    """Painted wall: the colour with a faint photographic plaster relief (gravel at low contrast)."""
    n = TEXTURE_SIZE
    rel = cv2.GaussianBlur(lib.images["gravel"].astype(np.float32), (0, 0), 2.0) / 255.0 - 0.5
    rel = cv2.resize(rel, (n, n))
    img = colour * (1 + 0.06 * rel[:, :, None] + 0.03 * _noise(rng, (n, n), 128)[:, :, None])
    return np.clip(img, 0, 255).astype(np.uint8)


def fabric_texture(rng: np.random.Generator, lib: PhotoLibrary, colour: np.ndarray) -> np.ndarray:
    """Woven fabric (rug, upholstery): a weave of two thread tones with the grass photo as fibre."""
    n = TEXTURE_SIZE
    yy, xx = np.mgrid[0:n, 0:n]
    weave = (((yy // 3) + (xx // 3)) % 2).astype(np.float32)
    fib = cv2.resize(lib.images["grass"].astype(np.float32), (n, n)) / 255.0 - 0.5
    img = colour * (0.85 + 0.15 * weave[:, :, None] + 0.25 * fib[:, :, None])
    band = (yy // 64) % 3 == 0
    img[band] = img[band] * 0.8 + np.asarray(colour)[::-1] * 0.2
    return np.clip(img, 0, 255).astype(np.uint8)


def photo_texture(lib: PhotoLibrary, name: str, rng: np.random.Generator) -> np.ndarray:
    """A poster or picture on the wall: a crop of a colour photograph."""
    w = rng.uniform(0.5, 0.9)
    x0, y0 = rng.uniform(0, 1 - w, 2)
    return lib.crop(name, (x0, y0, x0 + w, y0 + w), (TEXTURE_SIZE, TEXTURE_SIZE))


def skin_texture(rng: np.random.Generator) -> np.ndarray:
    """Skin: a warm tone with faint blotches and pores."""
    n = TEXTURE_SIZE // 2
    tone = np.array([205.0, 150.0, 120.0]) * rng.uniform(0.55, 1.05)
    img = tone * (1 + 0.06 * _noise(rng, (n, n), 32)[:, :, None] + 0.03 * rng.standard_normal((n, n, 1)))
    img = np.clip(img, 0, 255).astype(np.uint8)
    return cv2.resize(img, (TEXTURE_SIZE, TEXTURE_SIZE), interpolation=cv2.INTER_LINEAR)
