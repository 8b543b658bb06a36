"""The "Physical properties" panel of the `physgs` model in nerfstudio's viewer (``ns-viewer`` or training).

Built only from nerfstudio 1.1.5's viewer elements (``ViewerButton``, ``ViewerDropdown``, ``ViewerText``,
``ViewerControl`` for clicks, rectangles, the camera and the crop box) plus a markdown element on
nerfstudio's ``ViewerElement`` base (1.1.5 has none). nerfstudio finds them by walking the pipeline's
modules (``viewer.utils.parse_object``), so the panel is a parameter-free ``nn.Module`` of the model (nothing in
checkpoints) and its elements appear in the viewer's Control tab under ``model/physical_properties`` in the
alphabetical order of their attribute names.

* legend: every material's colour and name (materials.json), and the fixed colour scale of the output shown;
* material colours: dominant material, or the probability of one chosen material; uncertainty of: which
  property the `aleatoric`, `epistemic` and `total_uncertainty` outputs describe;
* *Pick a point*, then click: :func:`.query.query_pixel` on the click's pixel, the answer in the panel, the
  point marked in 3-D; *Point as JSON* puts the answer into the text field (select it and copy) and writes
  ``viewer_points/<time>.json`` beside the config: a server cannot write into the browser's clipboard;
* *Mass*: :func:`.mass.selection_mass` on the enabled crop box or the last rectangle (*Draw a rectangle*), in a
  background thread with its progress in the panel.
"""

from __future__ import annotations

import json
import tempfile
import threading
import time
import traceback
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch
from nerfstudio.viewer.viewer_elements import (
    ViewerButton,
    ViewerClick,
    ViewerControl,
    ViewerDropdown,
    ViewerElement,
    ViewerRectSelect,
    ViewerText,
)
from PIL import Image, ImageDraw

from .display import ViewerSettings, gaussian_materials
from .mass import Selection, box_from_obb, box_from_rectangle, selection_mass
from .query import PointQuery, query_pixel, ray_weights
from .scales import COLORMAP, DisplayScale

__all__ = ["PhysicalPropertiesPanel", "ViewerMarkdown"]

MATERIAL_VIEWS = {"dominant material": "dominant", "probability of one material": "probability"}
SCALE_RATIO = 10.0  # nerfstudio.viewer.viewer.VISER_NERFSTUDIO_SCALE_RATIO (imported lazily: viser start-up)


class ViewerMarkdown(ViewerElement[str]):
    """Markdown text in the panel (viser's markdown, with images from ``image_root``)."""

    def __init__(self, content: str, image_root: Callable[[], Path] | None = None, visible: bool = True):
        super().__init__("markdown", visible=visible)
        self._content = content
        self.image_root = image_root
        """called when the element is installed: the folder of the images the markdown names (no parentheses
        may follow an image in the text: viser's image pattern would swallow them)"""

    def _create_gui_handle(self, viser_server: Any) -> None:
        root = self.image_root() if self.image_root is not None else None
        self.gui_handle = viser_server.gui.add_markdown(self._content, image_root=root, visible=self.visible)

    def install(self, viser_server: Any) -> None:
        self._create_gui_handle(viser_server)

    @property
    def content(self) -> str:
        return self._content

    @content.setter
    def content(self, text: str) -> None:
        self._content = text
        if self.gui_handle is not None:
            self.gui_handle.content = text  # type: ignore[union-attr]


def legend_image(names: list[str], colors: torch.Tensor, path: Path) -> Path:
    """A PNG of the legend: one colour swatch and name per material."""
    row = 18
    img = Image.new("RGB", (220, row * len(names) + 4), (33, 37, 41))
    draw = ImageDraw.Draw(img)
    for i, (name, c) in enumerate(zip(names, (colors.reshape(-1, 3).clamp(0, 1) * 255).round().int().tolist())):
        y = 2 + i * row
        draw.rectangle([4, y + 2, 30, y + row - 3], fill=tuple(c))
        draw.text((38, y + 3), f"{i + 1}  {name}", fill=(230, 230, 230))
    img.save(path)
    return path


def colourbar_image(path: Path) -> Path:
    from nerfstudio.utils.colormaps import apply_float_colormap

    ramp = apply_float_colormap(torch.linspace(0, 1, 256)[:, None], colormap=COLORMAP)  # [256, 3]
    bar = (ramp[None].expand(14, -1, -1).numpy() * 255).astype(np.uint8)
    Image.fromarray(bar).save(path)
    return path


class PhysicalPropertiesPanel(torch.nn.Module):
    """The panel (module doc). ``model``: a PhysGSModel with ``viewer_settings``."""

    def __init__(self, model: Any):
        super().__init__()
        object.__setattr__(self, "_model", model)  # a back reference, not a sub-module
        self._assets: Path | None = None
        names = list(model.legend.names)
        s: ViewerSettings = model.viewer_settings
        keys = list(model.property_keys)
        self._keys = keys
        self._last_query: PointQuery | None = None
        self._rect: Selection | None = None
        self._scales: dict[str, DisplayScale] = {}
        self._shown: tuple | None = None
        self._busy = threading.Lock()
        sim = " [SIMULATED VLM]" if model.legend.simulated else ""
        lifted = ("\n\n*Material map: lifted evidence (material_head=lifted); none until the first lifting "
                  "(`--pipeline.lifting-every N` lifts while training).*"
                  if getattr(model, "material_head", None) == "lifted" else "")  # fmt: skip
        self.a_legend = ViewerMarkdown(f"**Materials**{sim}\n\n![legend](legend.png){lifted}", self._images)
        self.b_scale = ViewerMarkdown("**Colour scale**: choose a property in *Output type*.", self._images)
        self.c_material_view = ViewerDropdown("Material colours", "dominant material", list(MATERIAL_VIEWS),
                                              cb_hook=self._on_settings)  # fmt: skip
        self.d_material = ViewerDropdown("Material", names[0], names, cb_hook=self._on_settings)
        self.e_uncertainty = ViewerDropdown("Uncertainty of", s.uncertainty_property, keys, cb_hook=self._on_settings)
        self.f_pick = ViewerButton("Pick a point", cb_hook=self._on_pick)
        self.g_point = ViewerMarkdown("Press *Pick a point*, then click the object.")
        self.h_json_button = ViewerButton("Point as JSON", cb_hook=self._on_json)
        self.i_json = ViewerText("Point JSON", "", hint="the last point's answer as JSON: select it and copy")
        self.j_rectangle = ViewerButton("Draw a rectangle", cb_hook=self._on_draw)
        self.k_mass = ViewerButton("Mass", cb_hook=self._on_mass)
        self.l_mass = ViewerMarkdown("*Mass*: enable *Crop Viewport* (Control tab) or draw a rectangle around the "
                                     "object, then press *Mass*.")  # fmt: skip
        self.control = ViewerControl()

    # ------------------------------------------------------------------ settings and legend
    def _images(self) -> Path:
        """The legend and colour-bar PNGs, written once, when the viewer installs the panel."""
        if self._assets is None:
            self._assets = Path(tempfile.mkdtemp(prefix="physgs_viewer_"))
            legend_image(list(self._model.legend.names), self._model.material_colors.detach().cpu(),
                         self._assets / "legend.png")  # fmt: skip
            colourbar_image(self._assets / "colourbar.png")
        return self._assets

    def _on_settings(self, _: Any) -> None:
        s = self._model.viewer_settings
        s.material_view = MATERIAL_VIEWS[self.c_material_view.value]
        s.material_index = list(self._model.legend.names).index(self.d_material.value)
        s.uncertainty_property = self.e_uncertainty.value

    def _current_output(self) -> str | None:
        viewer = getattr(self.control, "viewer", None)
        try:
            return viewer.control_panel.output_render if viewer is not None else None
        except Exception:  # noqa: BLE001  (the control panel is not built yet)
            return None

    def note_scales(self, scales: dict[str, DisplayScale]) -> None:
        """Called by every render: describe the scale of the output the viewer shows (when it changed)."""
        self._scales = scales
        shown = self._current_output()
        if shown == "material" and self._model.viewer_settings.material_view == "probability":
            shown = "material_probability"
        key = (shown, scales[shown].describe() if shown in scales else None, self.d_material.value)
        if key == self._shown:  # unchanged (a new uncertainty property or material changes the scale's label)
            return
        self._shown = key
        if shown in scales:
            sc = scales[shown]
            what = f" of {self.d_material.value}" if shown == "material_probability" else ""
            self.b_scale.content = (f"**Colour scale** ({shown}{what}): {sc.describe()}\n\n![scale](colourbar.png)\n\n"
                                    "Grey, dimmed RGB: no material evidence.")  # fmt: skip
        else:
            self.b_scale.content = "**Colour scale**: choose a property in *Output type*."

    # ------------------------------------------------------------------ click
    def _on_pick(self, _: Any) -> None:
        self.g_point.content = "Click a point of the object in the view."
        self.control.register_pointer_cb("click", self._on_click)

    def _camera(self) -> tuple[Any, int, int]:
        """The client's camera at the viewer's full render size (its *Max res*), as nerfstudio renders it."""
        clients = self.control.server.get_clients()
        if not clients:
            raise RuntimeError("no viewer client is connected")
        aspect = float(next(iter(clients.values())).camera.aspect)
        viewer = getattr(self.control, "viewer", None)
        res = int(viewer.control_panel.max_res) if viewer is not None else 512
        W, H = (res, max(1, int(res / aspect))) if aspect > 1 else (max(1, int(res * aspect)), res)
        cam = self.control.get_camera(H, W)
        if cam is None:
            raise RuntimeError("no viewer client is connected")
        return cam, int(W), int(H)

    def run_mismatch(self) -> str | None:
        """Why this run's legend and maps are not the dataset's any more (its manifest,
        :mod:`physgs_nerfstudio.runfiles.manifest`), checked once; None when they are or cannot be checked. The
        panel then answers no point and no mass, and says why in its legend."""
        if getattr(self, "_mismatch", False) is not False:
            return self._mismatch
        from physgs_nerfstudio.runfiles.manifest import RunManifestError, check_manifest, dataset_dir

        self._mismatch = None
        viewer, run_dir = getattr(self.control, "viewer", None), self._run_dir()
        dm = getattr(getattr(viewer, "pipeline", None), "datamanager", None)
        dpo = getattr(dm, "train_dataparser_outputs", None)
        data_dir = dataset_dir(getattr(getattr(dm, "config", None), "data", None))
        if run_dir is None or dpo is None or data_dir is None:
            return None
        try:
            check_manifest(run_dir, data_dir, dpo.metadata)
        except RunManifestError as err:
            self._mismatch = " ".join(str(err).split())
            self.a_legend.content = f"**This run does not match its dataset**: {self._mismatch}"
        return self._mismatch

    def _on_click(self, click: ViewerClick) -> None:
        self.control.unregister_pointer_cb()
        if self.run_mismatch() is not None:
            self.g_point.content = f"Not answered: {self._mismatch}"
            return
        try:
            q = self.query(click.screen_pos)
        except Exception as err:  # noqa: BLE001  (shown in the panel; the viewer keeps running)
            self.g_point.content = f"Query failed: {type(err).__name__}: {err}"
            return
        self._last_query = q
        self.g_point.content = "\n\n".join(q.lines())
        if q.hit and q.point is not None:
            scene = self.control.server.scene
            pos = tuple(float(x) * SCALE_RATIO for x in q.point)
            scene.add_icosphere("/physgs/point", radius=0.05, color=(255, 0, 255), position=pos)
            top = q.materials[0]["name"] if q.materials else "not measured"
            scene.add_label("/physgs/point/label", text=top)

    @torch.no_grad()
    def query(self, screen_pos: tuple[float, float]) -> PointQuery:
        """The answer for a click at ``screen_pos`` (normalised OpenCV screen coordinates) in the current view."""
        from physgs_nerfstudio.geometry.capture import viewmat_from_c2w

        m = self._model
        cam, W, H = self._camera()
        cam = cam.to(m.device)
        u, v = min(screen_pos[0] * W, W - 1e-3), min(screen_pos[1] * H, H - 1e-3)
        keep = slice(None) if m.crop_box is None else m.crop_box.within(m.means).squeeze(-1)
        K = cam.get_intrinsics_matrices()[0]
        c2w = cam.camera_to_worlds[0]
        rw = ray_weights(m.means[keep], m.quats[keep], torch.exp(m.scales[keep]), torch.sigmoid(m.opacities[keep])[:, 0],
                         viewmat_from_c2w(c2w), K, W, H, (u, v))  # fmt: skip
        if not isinstance(keep, slice):
            rw.ids = torch.nonzero(keep).squeeze(-1)[rw.ids]
        gm = gaussian_materials(m)
        return query_pixel(rw, gm, m.material_nig(), m.log_space, property_keys=self._keys,
                           material_names=list(m.legend.names), camera_to_world=c2w, K=K, pixel=(u, v),
                           metres_per_unit=self._metres_per_unit(), min_coverage=m.viewer_settings.min_coverage,
                           simulated=bool(m.legend.simulated))  # fmt: skip

    def _run_dir(self) -> Path | None:
        viewer = getattr(self.control, "viewer", None)
        return Path(viewer.log_filename).parent if viewer is not None else None

    def _metres_per_unit(self) -> float:
        from physgs_nerfstudio.export.scale import read_dataparser_scale, resolve_scale

        run_dir = self._run_dir()
        if run_dir is None:
            return 1.0
        return resolve_scale(read_dataparser_scale(run_dir)).metres_per_unit

    def _on_json(self, _: Any) -> None:
        q = self._last_query
        if q is None:
            self.i_json.value = ""
            self.g_point.content = "No point yet: press *Pick a point* and click the object."
            return
        text = json.dumps(q.to_dict(), default=float)
        self.i_json.value = text
        run_dir = self._run_dir()
        if run_dir is not None:
            path = run_dir / "viewer_points" / f"{time.strftime('%Y%m%d-%H%M%S')}.json"
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(json.dumps(q.to_dict(), indent=2, default=float))
            self.g_point.content = "\n\n".join([*q.lines(), f"JSON in the *Point JSON* field and in `{path}`"])

    # ------------------------------------------------------------------ selection and mass
    def _on_draw(self, _: Any) -> None:
        self.l_mass.content = "Drag a rectangle around the object in the view."
        self.control.register_pointer_cb("rect-select", self._on_rect)

    def _on_rect(self, rect: ViewerRectSelect) -> None:
        from physgs_nerfstudio.geometry.capture import viewmat_from_c2w

        self.control.unregister_pointer_cb()
        m = self._model
        try:
            cam, W, H = self._camera()
            gm = gaussian_materials(m)
            self._rect = box_from_rectangle(m.means.detach(), gm.measured, viewmat_from_c2w(cam.camera_to_worlds[0].to(m.device)),
                                            cam.get_intrinsics_matrices()[0].to(m.device), W, H,
                                            (tuple(rect.min_bounds), tuple(rect.max_bounds)))  # fmt: skip
        except Exception as err:  # noqa: BLE001
            self.l_mass.content = f"Rectangle not used: {err}"
            return
        self.l_mass.content = f"Rectangle: {self._rect.note}. Press *Mass*."

    def selection(self) -> Selection:
        """The enabled crop box, else the last rectangle."""
        viewer = getattr(self.control, "viewer", None)
        if viewer is not None and viewer.control_panel.crop_viewport:
            obb = viewer.control_panel.crop_obb
            return box_from_obb(obb.T, obb.R, obb.S)
        if self._rect is not None:
            return self._rect
        raise ValueError("nothing selected: enable Crop Viewport (Control tab) and fit its box to the object, or "
                         "press Draw a rectangle and drag one around it.")  # fmt: skip

    def _on_mass(self, _: Any) -> None:
        try:
            sel = self.selection()
        except ValueError as err:
            self.l_mass.content = str(err)
            return
        if not self._busy.acquire(blocking=False):
            self.l_mass.content += "\n\n(a mass computation is already running)"
            return
        point = self._last_query.point if self._last_query is not None and self._last_query.measured else None
        threading.Thread(target=self._mass_worker, args=(sel, point), daemon=True).start()

    def _mass_worker(self, sel: Selection, point: Any) -> None:
        from physgs_nerfstudio.export.command import run_from_pipeline
        from physgs_nerfstudio.mass import MassConfig

        t0 = time.perf_counter()
        head = f"**Mass** of the {sel.source} {[round(x, 3) for x in sel.bbox]}" + (f" ({sel.note})" if sel.note else "")
        say = lambda s: setattr(self.l_mass, "content", f"{head}\n\n{s}")
        try:
            say("loading the run's cameras and masks")
            viewer = self.control.viewer
            run_dir = self._run_dir()
            assert run_dir is not None
            run = run_from_pipeline(run_dir, viewer.pipeline)
            stamp = time.strftime("%Y%m%d-%H%M%S")
            report, path = selection_mass(run, MassConfig(), sel, run_dir / "viewer_mass" / stamp, point=point,
                                          progress=say)  # fmt: skip
            say("\n\n".join(mass_lines(report, path, time.perf_counter() - t0)))
        except Exception as err:  # noqa: BLE001  (shown in the panel; the viewer keeps running)
            traceback.print_exc()
            say(f"Mass failed: {type(err).__name__}: {err}")
        finally:
            self._busy.release()


def mass_lines(report: Any, path: Path, seconds: float) -> list[str]:
    """Markdown lines of a mass result: mean, interval, share per material, the report file."""
    pct = round(report.level * 100)
    sim = " [SIMULATED VLM]" if report.simulated else ""
    lo, hi = report.interval_kg
    lines = [f"**{report.mean_kg:.4g} kg**{sim}, {pct}% interval [{lo:.4g}, {hi:.4g}] kg"]
    for m in sorted(report.materials, key=lambda m: -m.mass_share):
        if m.mass_share < 1e-3 and m.volume_share < 1e-3:
            continue
        lines.append(f"{m.name}: {m.mass_share:.0%} of the mass ({m.mass_mean_kg:.3g} kg, {m.volume_model}), "
                     f"{m.volume_share:.0%} of the volume")  # fmt: skip
    lines.append(f"{report.geometry.get('selected_gaussians', '?')} Gaussians, {seconds:.0f} s; report: `{path}`")
    return lines
