"""What the embedded 3-D view really draws, read from its pixels.

The scene API (``GET /viewer/scene``) says which nodes a view holds; only the pixels say that
the browser drew them.  These helpers screenshot the page's viser iframe with viser's own
panel and notifications masked out (their legend gradient and buttons would count as scene
colours), and count the pixels of the colours the scene must show:

- the part's slate (``Palette.mesh``, lit: its shades keep blue above red, low saturation);
- an exact line colour (lines are unlit: their inner pixels carry the drawn RGB);
- the two saturated ends of the diverging standoff-error / deviation scale
  (``app.viewer.colors``): strong blue below the nominal, strong red above it.

A blank canvas (white background and grey grid) has none of them.
"""

from __future__ import annotations

import io
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from PIL import Image

try:
    from playwright.sync_api import Error as PlaywrightError
except ImportError:  # the browser tests skip (see conftest); the module must still import
    PlaywrightError = Exception  # type: ignore[misc,assignment]

from app.viewer.colors import DIVERGING_STOPS

# viser's floating control panel (mantine Paper) and its notifications (e.g. the software
# WebGL notice): masked, so that only the canvas is counted
PANEL_SELECTORS = (".mantine-Paper-root", ".mantine-Notification-root")
# the diverging scale's anchors (blue, white, red) from its legend stops
ANCHORS = np.array([[int(hex_[i:i + 2], 16) for i in (1, 3, 5)] for _pos, hex_ in DIVERGING_STOPS], float)


@dataclass(frozen=True)
class Counts:
    """Pixels of each class in one screenshot of the view (masked areas excluded)."""

    total: int
    slate: int
    blue_end: int      # diverging scale, t < 0.3 (well below the nominal)
    red_end: int       # diverging scale, t > 0.7 (well above the nominal)
    exact: dict[tuple[int, int, int], int]

    def __str__(self) -> str:
        exact = ", ".join(f"{rgb}: {n}" for rgb, n in self.exact.items())
        return (f"{self.total} px: slate {self.slate}, diverging blue {self.blue_end}, red {self.red_end}"
                + (f", {exact}" if exact else ""))


def view_image(page) -> np.ndarray:  # type: ignore[no-untyped-def]
    """(h, w, 3) uint8 screenshot of ``#viewer-iframe`` with viser's panel masked white.  The
    page's region of the iframe is captured (an element screenshot waits for the element to
    be "stable", which a loaded machine re-laying out the page may not grant in time)."""
    frame = page.frame_locator("#viewer-iframe")
    masks = [frame.locator(s) for s in PANEL_SELECTORS]
    iframe = page.locator("#viewer-iframe")
    iframe.scroll_into_view_if_needed()
    box = iframe.bounding_box()
    if box is None:
        raise AssertionError("the 3-D view's iframe is not on the page")
    png = page.screenshot(clip=box, mask=masks, mask_color="#FFFFFF", animations="disabled")
    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))


def slate_mask(img: np.ndarray) -> np.ndarray:
    """Shades of the lit slate part: blue 8-70 above red, green between them, not saturated,
    neither near-white (background) nor near-black."""
    rgb = img.astype(int)
    r, g, b = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    spread = rgb.max(axis=-1) - rgb.min(axis=-1)
    return (b - r >= 8) & (b - r <= 70) & (g >= r - 4) & (g <= b + 4) & (spread <= 75) & (b >= 45) & (b <= 215)


def diverging_position(img: np.ndarray, tolerance: float = 22.0) -> np.ndarray:
    """Per pixel: its position t (0..1) on the diverging scale's colour curve when it lies within
    ``tolerance`` (RGB distance) of it, else NaN."""
    curve = np.concatenate([np.linspace(ANCHORS[0], ANCHORS[1], 101)[:-1],
                            np.linspace(ANCHORS[1], ANCHORS[2], 101)])        # (201, 3), t = i / 200
    flat = img.reshape(-1, 3).astype(float)
    # only coloured pixels can lie near a saturated end: skip greys and near-whites quickly
    candidates = np.flatnonzero(flat.max(axis=1) - flat.min(axis=1) > 40)
    t = np.full(len(flat), np.nan)
    if len(candidates):
        d = np.linalg.norm(flat[candidates, None, :] - curve[None, :, :], axis=2)
        best = d.argmin(axis=1)
        near = d[np.arange(len(candidates)), best] <= tolerance
        t[candidates[near]] = best[near] / 200.0
    return t.reshape(img.shape[:2])


def count(img: np.ndarray, exact: tuple[tuple[int, int, int], ...] = (), tolerance: int = 30) -> Counts:
    t = diverging_position(img)
    rgb = img.astype(int)
    return Counts(total=int(img.shape[0] * img.shape[1]), slate=int(slate_mask(img).sum()),
                  blue_end=int(np.sum(t < 0.3)), red_end=int(np.sum(t > 0.7)),
                  exact={c: int(np.sum(np.abs(rgb - np.array(c)).max(axis=-1) <= tolerance)) for c in exact})


def wait_for_view(page, drawn: Callable[[Counts], bool], exact: tuple[tuple[int, int, int], ...] = (),  # type: ignore[no-untyped-def]
                  timeout_s: float = 60.0) -> tuple[Counts, np.ndarray]:
    """Screenshot the view until ``drawn(counts)`` holds (software GL needs a few frames);
    returns the last counts and image either way (the caller asserts)."""
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            img = view_image(page)
        except PlaywrightError:
            if time.monotonic() > deadline:
                raise
            continue
        counts = count(img, exact)
        if drawn(counts) or time.monotonic() > deadline:
            return counts, img
        page.wait_for_timeout(500)


def save_view_panel(page, path) -> None:  # type: ignore[no-untyped-def]
    """Save the page's 3-D view section (caption, canvas, viser's panel with its legend) for the
    screenshots, without viser's software-WebGL notice (not for operators with a GPU)."""
    close = page.frame_locator("#viewer-iframe").locator("[class*='Notification'] button")
    try:
        if close.count():
            close.first.click(timeout=2000)
    except PlaywrightError:
        pass
    section = page.locator("#viewer-panel")
    section.scroll_into_view_if_needed()
    # below the sticky page header
    section.evaluate("el => window.scrollTo(0, el.getBoundingClientRect().top + window.scrollY - 90)")
    page.wait_for_timeout(1000)   # a frame or two after the notice went
    box = section.bounding_box()
    if box is not None:
        page.screenshot(path=str(path), clip=box, animations="disabled")
