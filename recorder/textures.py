"""Seeded procedural textures (numpy + OpenCV): wallpapers, brick, wood, tiles, posters, doors.

Every generator takes a ``numpy.random.Generator`` and a size and returns an ``(h, w, 3)`` uint8
RGB image.  The patterns are chosen to be rich in oriented gradients (the estimator compares
gradient-orientation histograms) and varied enough that different places look different, as in the
paper's figure 12.  Sizes are in pixels at :data:`PX_PER_M` pixels per metre of wall.
"""

from __future__ import annotations

import colorsys
from collections.abc import Callable

import cv2
import numpy as np

PX_PER_M = 96  # texture resolution on walls: ~1 texel per screen pixel at 1.5 m with a 320 px image

Rng = np.random.Generator


def _colour(rng: Rng, *, sat: tuple[float, float] = (0.2, 0.7), val: tuple[float, float] = (0.4, 0.95)):
    h = rng.random()
    s = rng.uniform(*sat)
    v = rng.uniform(*val)
    return np.array(colorsys.hsv_to_rgb(h, s, v)) * 255.0


def _contrasting(rng: Rng, base: np.ndarray, amount: float = 0.45) -> np.ndarray:
    """A colour of similar hue but clearly different brightness from ``base``."""
    lum = base.mean() / 255.0
    factor = 1.0 - amount if lum > 0.5 else 1.0 + amount * 1.5
    tint = rng.uniform(-30, 30, size=3)
    return np.clip(base * factor + tint, 0, 255)


def _fill(h: int, w: int, colour: np.ndarray) -> np.ndarray:
    return np.broadcast_to(colour.astype(np.uint8), (h, w, 3)).copy()


def _grain(rng: Rng, img: np.ndarray, amount: float = 6.0) -> np.ndarray:
    """Add fine seeded noise so flat areas are not perfectly flat (as with real paint and paper)."""
    noise = rng.normal(0.0, amount, size=img.shape[:2])[..., None]
    return np.clip(img.astype(np.float32) + noise, 0, 255).astype(np.uint8)


# ------------------------------------------------------------------------------------ wallpapers


def stripes(rng: Rng, h: int, w: int) -> np.ndarray:
    a = _colour(rng)
    b = _contrasting(rng, a)
    period = int(rng.integers(12, 48))
    duty = rng.uniform(0.2, 0.6)
    horizontal = rng.random() < 0.25
    n = h if horizontal else w
    t = np.arange(n)
    line = np.where(((t % period) < duty * period)[:, None], a, b)
    if rng.random() < 0.5:  # pinstripe
        line[(t % period) == period // 2 + int(duty * period / 2)] = _contrasting(rng, b, 0.7)
    img = line[:, None, :].repeat(w, axis=1) if horizontal else line[None, :, :].repeat(h, axis=0)
    return np.ascontiguousarray(img.astype(np.uint8))


def diamonds(rng: Rng, h: int, w: int) -> np.ndarray:
    a = _colour(rng)
    b = _contrasting(rng, a)
    sx, sy = rng.uniform(14, 40), rng.uniform(20, 56)
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    u, v = np.floor(x / sx + y / sy), np.floor(x / sx - y / sy)
    mask = ((u + v) % 2 == 0)[..., None]
    img = np.where(mask, a, b).astype(np.uint8)
    if rng.random() < 0.6:  # outline the diamonds
        edges = (np.abs(((x / sx + y / sy) % 1) - 0.5) > 0.46) | (
            np.abs(((x / sx - y / sy) % 1) - 0.5) > 0.46
        )
        img[edges] = _contrasting(rng, a, 0.8)
    return img


def dots(rng: Rng, h: int, w: int) -> np.ndarray:
    bg = _colour(rng, val=(0.6, 0.95))
    fg = _contrasting(rng, bg, 0.6)
    img = _fill(h, w, bg)
    step = int(rng.integers(14, 36))
    radius = max(2, int(step * rng.uniform(0.15, 0.35)))
    square = rng.random() < 0.3
    for row, y in enumerate(range(step // 2, h + step, step)):
        offset = step // 2 if row % 2 else 0
        for x in range(offset, w + step, step):
            if square:
                cv2.rectangle(img, (x - radius, y - radius), (x + radius, y + radius), fg.tolist(), -1)
            else:
                cv2.circle(img, (x, y), radius, fg.tolist(), -1, cv2.LINE_AA)
    return img


def damask(rng: Rng, h: int, w: int) -> np.ndarray:
    """A mirrored ornamental motif (ellipses, curls, a stem) on a tinted ground, tiled."""
    bg = _colour(rng, sat=(0.2, 0.6), val=(0.35, 0.8))
    fg = _contrasting(rng, bg, 0.5)
    tw, th = int(rng.integers(40, 72)), int(rng.integers(56, 96))
    tile = _fill(th, tw, bg)
    half = tile[:, : tw // 2].copy()
    for _ in range(int(rng.integers(3, 7))):
        centre = (int(rng.integers(tw // 6, tw // 2)), int(rng.integers(th // 8, th - th // 8)))
        axes = (int(rng.integers(3, tw // 4)), int(rng.integers(3, th // 5)))
        angle = float(rng.uniform(0, 180))
        thick = -1 if rng.random() < 0.5 else 2
        cv2.ellipse(
            half, centre, axes, angle, 0, float(rng.uniform(180, 360)), fg.tolist(), thick, cv2.LINE_AA
        )
    cv2.line(half, (tw // 2 - 1, 0), (tw // 2 - 1, th), fg.tolist(), 2, cv2.LINE_AA)
    tile[:, : tw // 2] = half
    tile[:, tw - tw // 2 :] = half[:, ::-1]
    reps = (h // th + 2, w // tw + 2, 1)
    img = np.tile(tile, reps)
    shift = th // 2
    img[:, tw : 2 * tw] = np.roll(img[:, tw : 2 * tw], shift, axis=0)  # half-drop repeat
    return np.ascontiguousarray(img[:h, :w])


def brick(rng: Rng, h: int, w: int) -> np.ndarray:
    mortar = _colour(rng, sat=(0.0, 0.15), val=(0.6, 0.85))
    base = _colour(rng, sat=(0.4, 0.7), val=(0.4, 0.7))
    if rng.random() < 0.6:  # mostly red-brown bricks
        base = np.array([rng.uniform(130, 190), rng.uniform(50, 90), rng.uniform(30, 60)])
    img = _fill(h, w, mortar)
    bh = int(rng.integers(18, 26))
    bw = int(bh * rng.uniform(2.0, 2.6))
    gap = 2
    for row, y in enumerate(range(0, h, bh)):
        offset = -(bw // 2) if row % 2 else 0
        for x in range(offset, w, bw):
            c = np.clip(base * rng.uniform(0.75, 1.2) + rng.normal(0, 8, 3), 0, 255)
            cv2.rectangle(img, (x + gap, y + gap), (x + bw - gap, y + bh - gap), c.tolist(), -1)
    return _grain(rng, img, 8.0)


def wood(rng: Rng, h: int, w: int) -> np.ndarray:
    """Vertical planks with wavy grain lines (wood panelling)."""
    base = np.array([rng.uniform(110, 190), rng.uniform(70, 120), rng.uniform(30, 70)])
    plank = int(rng.integers(20, 44))
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    phase = rng.uniform(0, 6.28, size=w // plank + 2)[(x // plank).astype(int)]
    grain = np.sin((x + 3.0 * np.sin(y / rng.uniform(20, 60) + phase)) * rng.uniform(0.5, 1.2))
    shade = rng.uniform(0.8, 1.15, size=w // plank + 2)[(x // plank).astype(int)]
    img = base[None, None, :] * (shade * (0.85 + 0.15 * grain))[..., None]
    img[:, (np.arange(w) % plank) == 0] *= 0.45  # plank seams
    return np.clip(img, 0, 255).astype(np.uint8)


def tiles(rng: Rng, h: int, w: int) -> np.ndarray:
    grout = _colour(rng, sat=(0.0, 0.1), val=(0.5, 0.9))
    base = _colour(rng, sat=(0.1, 0.6), val=(0.5, 0.95))
    alt = _contrasting(rng, base, 0.3)
    size = int(rng.integers(16, 40))
    img = _fill(h, w, grout)
    checker = rng.random() < 0.5
    for j, y in enumerate(range(0, h, size)):
        for i, x in enumerate(range(0, w, size)):
            c = alt if checker and (i + j) % 2 else base
            c = np.clip(c * rng.uniform(0.92, 1.06), 0, 255)
            cv2.rectangle(img, (x + 1, y + 1), (x + size - 2, y + size - 2), c.tolist(), -1)
    return img


def panelled(rng: Rng, h: int, w: int) -> np.ndarray:
    """Two-tone painted wall: a darker dado below a rail, plain paint above, raised-panel outlines."""
    top = _colour(rng, sat=(0.05, 0.4), val=(0.7, 0.95))
    low = _contrasting(rng, top, 0.4)
    img = _fill(h, w, top)
    rail = int(h * rng.uniform(0.3, 0.42))
    img[h - rail :] = low
    cv2.rectangle(img, (0, h - rail - 4), (w, h - rail + 2), _contrasting(rng, low, 0.5).tolist(), -1)
    pw = int(rng.integers(40, 80))
    for x in range(8, w - 20, pw):
        cv2.rectangle(img, (x, h - rail + 12), (min(w - 8, x + pw - 16), h - 24), (low * 0.7).tolist(), 2)
    return _grain(rng, img, 4.0)


WALLPAPERS: tuple[Callable[[Rng, int, int], np.ndarray], ...] = (
    stripes,
    diamonds,
    dots,
    damask,
    brick,
    wood,
    tiles,
    panelled,
)


# ------------------------------------------------------------------------------ pictures, doors


def poster(rng: Rng, h: int, w: int) -> np.ndarray:
    """A poster: coloured ground, bold shapes, a title bar and rows of text-like marks."""
    img = _fill(h, w, _colour(rng, val=(0.5, 1.0)))
    for _ in range(int(rng.integers(3, 8))):
        c = _colour(rng, sat=(0.5, 1.0)).tolist()
        kind = rng.integers(3)
        p = (int(rng.integers(0, w)), int(rng.integers(0, int(h * 0.7))))
        if kind == 0:
            cv2.circle(img, p, int(rng.integers(w // 10, w // 3)), c, -1, cv2.LINE_AA)
        elif kind == 1:
            q = (int(rng.integers(0, w)), int(rng.integers(0, int(h * 0.7))))
            cv2.rectangle(img, p, q, c, -1)
        else:
            pts = rng.integers(0, [w, int(h * 0.7)], size=(3, 2)).astype(np.int32)
            cv2.fillPoly(img, [pts], c, cv2.LINE_AA)
    ink = (0, 0, 0) if img.mean() > 110 else (245, 245, 245)
    title_h = max(4, h // 12)
    y = int(h * 0.72)
    cv2.rectangle(img, (w // 10, y), (w // 10 + int(w * rng.uniform(0.4, 0.8)), y + title_h), ink, -1)
    y += title_h + 6
    while y < h - 8:
        x = w // 10
        while x < w - w // 10:
            word = int(rng.integers(4, 16))
            cv2.rectangle(img, (x, y), (min(x + word, w - w // 10), y + 3), ink, -1)
            x += word + 4
        y += 8
    return img


def painting(rng: Rng, h: int, w: int) -> np.ndarray:
    """A landscape-ish painting: sky gradient, a sun, layered hills, a few strokes."""
    top, bottom = _colour(rng, sat=(0.2, 0.7)), _colour(rng, sat=(0.2, 0.7))
    t = np.linspace(0, 1, h)[:, None, None]
    img = (top * (1 - t) + bottom * t).repeat(w, axis=1)
    img = np.ascontiguousarray(img.astype(np.uint8))
    sun = (int(rng.integers(w // 5, 4 * w // 5)), int(rng.integers(h // 8, h // 3)))
    cv2.circle(
        img, sun, int(rng.integers(h // 14, h // 7)), _colour(rng, val=(0.85, 1)).tolist(), -1, cv2.LINE_AA
    )
    for layer in range(int(rng.integers(2, 4))):
        base = int(h * (0.45 + 0.15 * layer))
        xs = np.linspace(0, w, 9)
        ys = base + rng.normal(0, h * 0.06, size=9)
        pts = np.array([[0, h], *zip(xs, ys, strict=True), [w, h]], dtype=np.int32)
        cv2.fillPoly(img, [pts], _colour(rng, val=(0.2, 0.7)).tolist(), cv2.LINE_AA)
    for _ in range(int(rng.integers(4, 12))):
        p = rng.integers(0, [w, h], size=2)
        q = p + rng.integers(-w // 5, w // 5, size=2)
        cv2.line(img, tuple(map(int, p)), tuple(map(int, q)), _colour(rng).tolist(), 2, cv2.LINE_AA)
    return img


def framed(rng: Rng, picture: np.ndarray) -> np.ndarray:
    """The picture inside a frame (wood, black or metal) with a white mat for paintings."""
    h, w = picture.shape[:2]
    frame = [np.array([110, 70, 35]), np.array([25, 25, 25]), np.array([180, 180, 185])][int(rng.integers(3))]
    border = max(3, min(h, w) // 14)
    out = _fill(h + 2 * border, w + 2 * border, frame)
    cv2.rectangle(out, (1, 1), (w + 2 * border - 2, h + 2 * border - 2), (frame * 0.6).tolist(), 1)
    out[border : border + h, border : border + w] = picture
    return out


def door(rng: Rng, h: int, w: int) -> np.ndarray:
    """A door leaf: wood or painted, with raised panels and a handle (the frame is drawn around it)."""
    img = (
        wood(rng, h, w) if rng.random() < 0.5 else _grain(rng, _fill(h, w, _colour(rng, val=(0.5, 0.95))), 3)
    )
    dark = (img.reshape(-1, 3).mean(axis=0) * 0.6).tolist()
    light = np.clip(img.reshape(-1, 3).mean(axis=0) * 1.25, 0, 255).tolist()
    m = w // 8
    rows = int(rng.integers(1, 4))
    ph = (h - 2 * m - (rows - 1) * m) // rows
    for r in range(rows):
        y0 = m + r * (ph + m)
        for x0, x1 in ((m, w // 2 - m // 2), (w // 2 + m // 2, w - m)):
            cv2.rectangle(img, (x0, y0), (x1, y0 + ph), dark, 2)
            cv2.line(img, (x0 + 2, y0 + 2), (x1 - 2, y0 + 2), light, 1)
    hy = int(h * 0.52)
    cv2.rectangle(img, (w - m - 8, hy - 3), (w - m + 4, hy + 3), (200, 190, 120), -1)
    cv2.circle(img, (w - m - 2, hy), 5, (170, 160, 90), -1, cv2.LINE_AA)
    return img


# ------------------------------------------------------------------------------ floors, ceiling


def floor_texture(rng: Rng, size: int = 256) -> np.ndarray:
    """A seamless floor texture (parquet, checker tiles or carpet) for a 2 m × 2 m repeat."""
    kind = rng.integers(3)
    if kind == 0:  # parquet: planks in a herringbone-ish block pattern
        img = np.empty((size, size, 3), np.uint8)
        q = size // 4
        for j in range(4):
            for i in range(4):
                block = wood(rng, q, q)
                if (i + j) % 2:
                    block = np.ascontiguousarray(np.transpose(block, (1, 0, 2)))
                img[j * q : (j + 1) * q, i * q : (i + 1) * q] = block
        return img
    if kind == 1:  # large checker tiles with grout
        a = _colour(rng, sat=(0.0, 0.3), val=(0.5, 0.95))
        b = _contrasting(rng, a, 0.35)
        img = _fill(size, size, a)
        q = size // 4
        for j in range(4):
            for i in range(4):
                c = b if (i + j) % 2 else a
                cv2.rectangle(img, (i * q + 1, j * q + 1), ((i + 1) * q - 2, (j + 1) * q - 2), c.tolist(), -1)
                cv2.rectangle(img, (i * q, j * q), ((i + 1) * q - 1, (j + 1) * q - 1), (90, 90, 90), 1)
        return _grain(rng, img, 3)
    base = _colour(rng, sat=(0.2, 0.6), val=(0.25, 0.55))  # carpet: coloured noise with a woven grid
    img = _grain(rng, _fill(size, size, base), 14)
    img[:: size // 16] = np.clip(img[:: size // 16] * 0.8, 0, 255).astype(np.uint8)
    img[:, :: size // 16] = np.clip(img[:, :: size // 16] * 0.8, 0, 255).astype(np.uint8)
    return img


def ceiling_texture(rng: Rng, size: int = 256) -> np.ndarray:
    """Suspended-ceiling tiles: speckled off-white with a grid (one 2 m × 2 m repeat = 4×4 tiles)."""
    img = _grain(rng, _fill(size, size, np.array([225.0, 222.0, 214.0])), 10)
    q = size // 4
    for k in range(5):
        cv2.line(img, (k * q, 0), (k * q, size), (150, 150, 145), 2)
        cv2.line(img, (0, k * q), (size, k * q), (150, 150, 145), 2)
    return img
