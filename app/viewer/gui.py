"""The viser side panel: job selector, visibility toggles, layer sliders and the
measured-versus-nominal deviation plots (uPlot, x axis in mm along the trace).

Nothing here can move a machine: the panel only changes what the view shows.
Callbacks fired by server-side value changes (``event.client is None``) are ignored, so
that a focus change coming from the API does not echo back as a new focus request.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

import numpy as np

from app.viewer.preview_draw import layer_label
from app.viewer.registry import SceneRegistry
from app.viewer.scene_data import FocusScene
from app.viewer.scenes import SceneBuilder
from app.viewer.text import user_text

log = logging.getLogger("conforma.viewer")
GROUPS = ("part", "traces", "probes", "curves", "toolpaths", "deviation", "layers", "axes", "heights", "surfaces",
          "head")
NO_JOB = "(none)"


class ViewerPanel:
    """GUI handles of the panel; ``refresh_jobs`` and ``show`` are called by the Viewer."""

    def __init__(self, server: Any, builder: SceneBuilder, registry: SceneRegistry,
                 on_select: Callable[[str | None, str | None], None],
                 list_jobs: Callable[[], list[tuple[str, str]]]) -> None:
        self.server = server
        self.builder = builder
        self.registry = registry
        self._on_select = on_select
        self._list_jobs = list_jobs
        self._choices: dict[str, tuple[str | None, str | None]] = {}
        gui = server.gui
        gui.configure_theme(control_layout="collapsible", control_width="small", show_logo=False,
                            show_share_button=False)
        self.title = gui.add_markdown("**Conforma** (view only): open a part or a job in the web pages.")
        with gui.add_folder("Focus"):
            self.selector = gui.add_dropdown("Job / part", [NO_JOB], initial_value=NO_JOB)
            self.refresh_button = gui.add_button("Refresh list", icon=None)
        with gui.add_folder("Show"):
            self.toggles = {g: gui.add_checkbox(g.capitalize(), True, visible=False) for g in GROUPS}
        self.legend_folder = gui.add_folder("Colour scale", visible=False)
        self.layer_folder = gui.add_folder("Layers", visible=False)
        self.plot_folder = gui.add_folder("Deviation", visible=False)
        self._dynamic: list[Any] = []
        self._sliders: dict[str, tuple[Any, Any, tuple[str, ...]]] = {}  # name -> (slider, caption, labels)
        self.selector.on_update(self._selected)
        self.refresh_button.on_click(lambda _event: self.refresh_jobs())
        for group, box in self.toggles.items():
            box.on_update(self._toggle_callback(group))

    # callbacks -------------------------------------------------------------------------
    def _selected(self, event: Any) -> None:
        if event.client is None:
            return
        part_id, job_id = self._choices.get(self.selector.value, (None, None))
        if part_id or job_id:
            self._on_select(part_id, job_id)

    def _toggle_callback(self, group: str) -> Callable[[Any], None]:
        def toggle(_event: Any) -> None:
            self.builder.set_group_visible(group, bool(self.toggles[group].value))
        return toggle

    # updates ---------------------------------------------------------------------------
    def refresh_jobs(self, current: str | None = None) -> None:
        """Fill the selector with recent parts and jobs (label -> (part_id, job_id)); each
        label is shown as text (:func:`user_text`, ``"label"``)."""
        try:
            entries = self._list_jobs()
        except Exception:  # the database may be busy; keep the old list
            log.exception("could not list jobs for the viewer")
            return
        self._choices = {NO_JOB: (None, None)}
        for label, ref in entries:
            self._choices[user_text(label, "label")] = (ref, None) if ref.startswith("part_") else (None, ref)
        self.selector.options = list(self._choices)
        if current is not None:
            chosen = next((lab for lab, ids in self._choices.items() if current in ids), None)
            if chosen is not None:
                self.selector.value = chosen

    def show(self, scene: FocusScene) -> None:
        """Rebuild the dynamic parts of the panel for ``scene`` (already drawn)."""
        for handle in self._dynamic:
            handle.remove()
        self._dynamic.clear()
        self._sliders.clear()
        gui = self.server.gui
        present = set(self.registry.groups())
        for group, box in self.toggles.items():
            box.visible = group in present
        self.title.content = f"**{user_text(scene.title, 'markdown')}**" + "".join(
            f"\n\n_{user_text(n, 'markdown')}_" for n in scene.notes)
        legends = self.registry.legends()
        self.legend_folder.visible = bool(legends)
        with self.legend_folder:
            for legend in legends:
                self._dynamic.append(gui.add_html(legend_html(legend)))
        previews = self.builder.previews
        self.layer_folder.visible = bool(self.builder.layer_stacks or self.builder.height_stacks or previews)
        with self.layer_folder:
            for name, preview in previews.items():   # up to layer k, nothing above
                self._slider(gui, name, tuple(layer_label(preview, k) for k in range(len(preview.layers))),
                             self.builder.show_preview_layer)
            for name, stack in self.builder.layer_stacks.items():
                self._slider(gui, name, stack.labels, self.builder.show_layer)
            for name, heights in self.builder.height_stacks.items():
                self._slider(gui, name, heights.labels, self.builder.show_height)
        self.plot_folder.visible = bool(scene.plots)
        with self.plot_folder:
            for plot in scene.plots:
                self._plot(gui, plot)

    def _slider(self, gui: Any, name: str, labels: tuple[str, ...], show: Callable[[str, int], int]) -> None:
        last = max(len(labels) - 1, 0)
        slider = gui.add_slider(user_text(name, "label"), min=0, max=max(last, 1), step=1, initial_value=last,
                                disabled=last == 0, hint="layer index")
        caption = gui.add_markdown(user_text(labels[last], "markdown") if labels else "")
        self.registry.set_slider(name, 0, last, last, list(labels))

        def moved(event: Any) -> None:
            if event.client is None:   # set by the server (the page's slider): already drawn
                return
            index = show(name, int(slider.value))
            caption.content = user_text(labels[index], "markdown")
            self.registry.set_slider(name, 0, last, index, list(labels))

        slider.on_update(moved)
        self._dynamic += [slider, caption]
        self._sliders[name] = (slider, caption, labels)

    def set_slider(self, name: str, index: int) -> None:
        """Move a layer slider to ``index`` (what the page's slider drew), without redrawing."""
        entry = self._sliders.get(name)
        if entry is not None:
            slider, caption, labels = entry
            slider.value = index
            caption.content = user_text(labels[index], "markdown")

    def _plot(self, gui: Any, plot: Any) -> None:
        from viser import uplot

        s = np.asarray(plot.s_mm, np.float64)
        dz = np.asarray(plot.dz_mm, np.float64)
        handle = gui.add_uplot(
            (s, dz),
            (uplot.Series(label="s (mm)"), uplot.Series(label="dz (mm)", stroke="#d33", width=2)),
            title=user_text(plot.title, "label"),
            scales={"x": uplot.Scale(time=False, auto=True), "y": uplot.Scale(auto=True)},
            axes=(uplot.Axis(label="mm along the trace"), uplot.Axis(label="dz (mm)")),
            aspect=1.6,
        )
        self.registry.add_plot(f"deviation/{plot.name}", plot.title, s.tolist(), dz.tolist(),
                               "mm along the trace", "dz (mm)")
        self._dynamic.append(handle)


def legend_html(legend: dict[str, Any]) -> str:
    """A legend as a gradient bar with its title, unit and the ends of the scale, plus the
    range the data really spans (``legend`` as :meth:`Legend.to_dict` gives it)."""
    stops = ", ".join(f"{color} {position * 100:.0f}%" for position, color in legend["stops"])
    lo, hi = legend["lo"], legend["hi"]
    mid = f"<span>{(lo + hi) / 2:.3g}</span>" if lo < 0 < hi else ""
    name, title, unit_text = (user_text(legend[k], "html") for k in ("name", "title", "unit"))
    return (f'<div class="conforma-legend" data-name="{name}" style="font-size:12px;margin:4px 0">'
            f'<div><b>{title}</b> ({unit_text})</div>'
            f'<div style="height:12px;border:1px solid #555;background:linear-gradient(to right, {stops})"></div>'
            '<div style="display:flex;justify-content:space-between">'
            f'<span>{lo:.3g}</span>{mid}<span>{hi:.3g}</span></div>'
            f'<div style="color:#555">data {legend["data_min"]:.3g} .. {legend["data_max"]:.3g} {unit_text}</div>'
            '</div>')
