"""Renders in Jupyter: a display that follows a render while it runs.

    from clpt.notebook import LiveView, live_render, side_by_side
    res = live_render(renderer, 64, width=128, height=128)   # the image updates in place, with progress
    res                                                       # a RenderResult shows as its image
    side_by_side([a.image, b.filtered], ["64 spp", "64 spp, filtered"])

LiveView is an on_update for Renderer.render. With ipywidgets installed it
draws an image widget and a progress bar; without them it uses IPython's
display updates (display_id), which every notebook front end and nbconvert
understand. Images are tone-mapped as the PNG writer does (clpt.image).
"""

from __future__ import annotations

import base64
import html

import numpy as np

from .image import png_bytes


def _widgets():
    try:
        import ipywidgets  # optional (notebooks): imported when a live view is made
    except ImportError:
        return None
    return ipywidgets


def _progress_text(u) -> str:
    h, w = u.shape
    rate = u.spp_done * h * w / max(u.elapsed, 1e-9)
    text = f"{u.spp_done:.4g}/{u.spp_total} spp, {u.elapsed:.1f} s, {rate / 1e6:.2f} Msamples/s"
    if u.final:
        return "done: " + text + (", filtered" if u.filtered is not None else "")
    frac = u.spp_done / max(u.spp_total, 1)
    if frac > 0:
        text += f", ETA {u.elapsed / frac - u.elapsed:.1f} s"
    return text


class LiveView:
    """Shows a render's image so far in the notebook cell it was made in.

    exposure: stops, as for PNGs; width: displayed width in pixels (default:
    the image's, at least 256); widgets: True/False to force ipywidgets on or
    off (default: used when installed). Pass it as on_update.
    """

    def __init__(self, *, exposure: float = 0.0, width: int | None = None, widgets: bool | None = None,
                 title: str = ""):
        from IPython.display import HTML, display  # optional (notebooks)

        self.exposure, self.width, self.title = exposure, width, title
        self.updates = 0
        self.last = None
        ipw = _widgets() if widgets is not False else None
        if widgets and ipw is None:
            raise ImportError("LiveView(widgets=True) needs ipywidgets: pip install ipywidgets")
        self._ipw = ipw
        if ipw is not None:
            self._label = ipw.HTML(html.escape(title or "waiting for the first pass"))
            self._bar = ipw.FloatProgress(min=0.0, max=1.0, value=0.0)
            self._image = ipw.Image(format="png")
            display(ipw.VBox([ipw.HBox([self._bar, self._label]), self._image]))
        else:
            self._text = display(HTML(html.escape(title or "waiting for the first pass")), display_id=True)
            self._picture = display(HTML(""), display_id=True)

    def _display_width(self, w: int) -> int:
        return self.width or max(w, 256)

    def __call__(self, u):
        from IPython.display import HTML, Image  # optional (notebooks)

        img = u.display_image() if u.final else u.image
        png = png_bytes(img, self.exposure)
        text = (f"{self.title}: " if self.title else "") + _progress_text(u)
        width = self._display_width(img.shape[1])
        if self._ipw is not None:
            self._image.value = png
            self._image.width = str(width)
            self._bar.value = 1.0 if u.final else min(u.spp_done / max(u.spp_total, 1), 1.0)
            self._label.value = html.escape(text)
        else:
            self._picture.update(Image(data=png, format="png", width=width))
            self._text.update(HTML(html.escape(text)))
        self.updates += 1
        self.last = u


def live_render(renderer, spp: int | None = None, *, exposure: float = 0.0, width_px: int | None = None,
                widgets: bool | None = None, title: str = "", update_interval: float = 0.5, **kw):
    """renderer.render(spp, **kw) with a LiveView following it; returns the RenderResult."""
    view = LiveView(exposure=exposure, width=width_px, widgets=widgets, title=title)
    return renderer.render(spp, on_update=view, update_interval=update_interval, **kw)


def _as_image(x) -> np.ndarray:
    img = getattr(x, "filtered", None)
    if img is None:
        img = getattr(x, "image", x)
    img = np.asarray(img, dtype=np.float32)
    if img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f"side_by_side: need H x W x 3 images or RenderResults (got shape {img.shape})")
    return img


def side_by_side(images, titles=None, *, exposure: float = 0.0, width: int | None = None):
    """Images (arrays or RenderResults: their filtered image when they have
    one) in a row with captions, as an IPython HTML object."""
    from IPython.display import HTML  # optional (notebooks)

    images = [_as_image(x) for x in images]
    titles = list(titles) if titles is not None else [""] * len(images)
    if len(titles) != len(images):
        raise ValueError(f"side_by_side: {len(images)} images but {len(titles)} titles")
    cells = []
    for img, t in zip(images, titles):
        src = base64.b64encode(png_bytes(img, exposure)).decode("ascii")
        w = width or max(img.shape[1], 256)
        cells.append(f'<figure style="margin:4px"><img src="data:image/png;base64,{src}" width="{w}" '
                     f'style="image-rendering:pixelated"/><figcaption style="text-align:center">'
                     f'{html.escape(str(t))}</figcaption></figure>')
    return HTML('<div style="display:flex;flex-wrap:wrap">' + "".join(cells) + "</div>")
