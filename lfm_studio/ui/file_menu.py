"""The File menu: new from preset, open, open raw light field, reconstruct a video, save, save as, recent files, exports.

Designs are written atomically by :func:`~lfm_studio.engine.design.save_design`; an
existing file other than the open document is never replaced without a confirmation
(the file dialogs' own overwrite prompt is off so the question is asked once, here).
Refused values on screen are not in the design in force: Save asks before writing the last
valid design without them, and closing or replacing the document asks before losing them
(:mod:`~lfm_studio.ui.refused_input`).
Recent files live in :class:`QSettings` under the organisation/application
``lfm_studio``; tests pass their own settings object. Exports (PSF stack, light-field
image, reconstruction) are ImageJ TIFFs from :mod:`lfm_studio.engine.io`, written on a
worker so a 1.7 GB stack does not freeze the window; an export that fails gets a dialog
(not only the status-bar line). Write errors name the user's file, never the temporary
file of the atomic writer, and say what to do (:func:`~lfm_studio.ui.failure_notices.write_error_text`).
"Open raw light field…" is :class:`~lfm_studio.ui.raw_frame_dialog.RawFrameActions`; "Reconstruct
light-field video…" is :class:`~lfm_studio.ui.video_dialog.VideoActions` (the window's viewer, if
any, shows its last frame).
"""

from __future__ import annotations

import re
from functools import partial
from pathlib import Path
from typing import Any

from qtpy.QtCore import QObject, QSettings
from qtpy.QtGui import QAction, QKeySequence
from qtpy.QtWidgets import QFileDialog, QMenu, QMessageBox, QWidget

from lfm_studio.engine.design import list_presets, load_design, load_preset, save_design
from lfm_studio.ui.edits import with_design_warnings
from lfm_studio.ui.failure_notices import show_failure, write_error_text
from lfm_studio.ui.raw_frame_dialog import RawFrameActions
from lfm_studio.ui.refused_input import confirm_save_refused, refused_text, unsaved_model_text
from lfm_studio.ui.state import StudioState
from lfm_studio.ui.video_dialog import VideoActions
from lfm_studio.widgets.jobs import JobOutcome, JobRunner

ORGANIZATION = APPLICATION = "lfm_studio"
RECENT_KEY = "recent_files"
DESIGN_FILTER = "Design files (*.json)"
TIFF_FILTER = "ImageJ TIFF (*.tif *.tiff)"
_Buttons = QMessageBox.StandardButton


def default_settings() -> QSettings:
    """The studio's settings (INI file in the user's configuration folder)."""
    return QSettings(QSettings.Format.IniFormat, QSettings.Scope.UserScope, ORGANIZATION, APPLICATION)


def _slug(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9]+", "_", name).strip("_").lower() or "design"


def _write_tiff(ctx: Any, write: Any, path: str) -> Path:
    """Export job: ``write(path)`` on a worker thread."""
    ctx.progress(0, 1, f"writing {Path(path).name}")
    return write(path)


class FileActions(QObject):
    """The File menu's actions for ``state``, with dialogs parented to ``window``."""

    def __init__(
        self,
        state: StudioState,
        window: QWidget,
        runner: JobRunner,
        *,
        settings: QSettings | None = None,
    ) -> None:
        super().__init__(window)
        self.state, self.window, self.runner = state, window, runner
        self.settings = settings if settings is not None else default_settings()
        self.last_failure: QMessageBox | None = None  # the dialog of the last failed export
        self.new_menu = QMenu("&New from preset", window)
        for name in list_presets():
            action = self.new_menu.addAction(name)
            action.setData(name)
        self.new_menu.triggered.connect(self._on_new_triggered)
        self.open_action = self._action("&Open…", QKeySequence.StandardKey.Open, self.open)
        self.raw_frames = RawFrameActions(state, window, runner)
        self.open_raw_action = self.raw_frames.action
        self.video = VideoActions(state, window, runner, viewer=getattr(window, "viewer", None))
        self.video_action = self.video.action
        self.save_action = self._action("&Save", QKeySequence.StandardKey.Save, self.save)
        self.save_as_action = self._action("Save &as…", QKeySequence.StandardKey.SaveAs, self.save_as)
        self.recent_menu = QMenu("Open &recent", window)
        self.recent_menu.triggered.connect(self._on_recent_triggered)
        self.export_psf_action = self._action("Export PSF stack…", None, self.export_psf)
        self.export_image_action = self._action("Export light-field image…", None, self.export_image)
        self.export_reconstruction_action = self._action(
            "Export reconstruction…", None, self.export_reconstruction
        )
        self.quit_action = self._action("&Quit", QKeySequence.StandardKey.Quit, self._on_quit)
        stored = self.settings.value(RECENT_KEY, []) or []
        stored = [stored] if isinstance(stored, str) else list(stored)
        state.set_recent_files(p for p in stored if Path(p).is_file())
        state.recent_files_changed.connect(self._on_recent_files)
        state.psf_changed.connect(self._update_exports)
        state.image_changed.connect(self._update_exports)
        state.reconstruction_changed.connect(self._update_exports)
        self._on_recent_files(state.recent_files)
        self._update_exports()

    def disconnect_state(self) -> None:
        state = self.state
        self.raw_frames.disconnect_state()
        self.video.disconnect_state()
        state.recent_files_changed.disconnect(self._on_recent_files)
        for signal in (state.psf_changed, state.image_changed, state.reconstruction_changed):
            signal.disconnect(self._update_exports)

    def _action(self, text: str, shortcut: Any, slot: Any) -> QAction:
        action = QAction(text, self)
        if shortcut is not None:
            action.setShortcut(QKeySequence(shortcut))
        action.triggered.connect(slot)
        return action

    def populate(self, menu: QMenu) -> None:
        """Fill ``menu`` (the window's File menu)."""
        menu.addMenu(self.new_menu)
        menu.addAction(self.open_action)
        menu.addMenu(self.recent_menu)
        menu.addAction(self.open_raw_action)
        menu.addAction(self.video_action)
        menu.addSeparator()
        menu.addAction(self.save_action)
        menu.addAction(self.save_as_action)
        menu.addSeparator()
        for action in (self.export_psf_action, self.export_image_action, self.export_reconstruction_action):
            menu.addAction(action)
        menu.addSeparator()
        menu.addAction(self.quit_action)

    # ----- documents -----

    def confirm_discard(self) -> bool:
        """Ask what to do with unsaved input (changes, refused values on screen, a trained model not
        saved to a checkpoint); True when it is fine to go on (saved or discarded)."""
        state = self.state
        if not state.unsaved_input:
            return True
        refused = refused_text(state.errors, "will not be saved") if state.errors else ""
        model = unsaved_model_text(state.unsaved_model) if state.unsaved_model else ""
        if not state.dirty:  # the design is saved; refused values and/or a trained model are unsaved
            if state.errors:
                them = "it" if len(state.errors) == 1 and not model else "them"
                title, text = "Refused values on screen", refused_text(state.errors, "will be lost")
            else:
                them, title, text = "it", "Unsaved trained model", ""
            answer = QMessageBox.question(
                self.window, title,
                " ".join(part for part in (text, model) if part) + f" Discard {them}?",
                _Buttons.Discard | _Buttons.Cancel, _Buttons.Cancel,
            )  # fmt: skip
            return answer == _Buttons.Discard
        answer = QMessageBox.question(
            self.window, "Unsaved changes",
            f"The design “{state.design.name}” has unsaved changes. Save them first?"
            + "".join(f"\n\n{part}" for part in (refused, model) if part),
            _Buttons.Save | _Buttons.Discard | _Buttons.Cancel, _Buttons.Save,
        )  # fmt: skip
        if answer == _Buttons.Save:
            return self.save(refused_asked=True)  # the question above named the refused values
        return answer == _Buttons.Discard

    def new_from_preset(self, name: str) -> bool:
        """Replace the document by the bundled preset ``name`` (after the unsaved-changes prompt)."""
        if not self.confirm_discard():
            return False
        design, warnings = with_design_warnings(load_preset, name)
        self.state.replace_design(design, file_path=None, warnings=warnings)
        return True

    def open(self, *_: Any) -> bool:
        """Choose a design file and open it."""
        if not self.confirm_discard():
            return False
        path, _filter = QFileDialog.getOpenFileName(self.window, "Open design", self._folder(), DESIGN_FILTER)
        return bool(path) and self.open_file(path, confirm=False)

    def open_file(self, path: str | Path, *, confirm: bool = True) -> bool:
        """Open the design file ``path``; a file that cannot be read is reported, nothing changes."""
        if confirm and not self.confirm_discard():
            return False
        try:
            design, warnings = with_design_warnings(load_design, path)
        except (OSError, ValueError) as error:
            QMessageBox.warning(self.window, "Cannot open design", str(error))
            return False
        self.state.replace_design(design, file_path=path, warnings=warnings)
        self.state.add_recent_file(Path(path).resolve())
        return True

    def save(self, *_: Any, refused_asked: bool = False) -> bool:
        """Save to the open document's file (Save as… when there is none).

        With refused values on screen, asks first whether to save the last valid design anyway
        (unless ``refused_asked``: the caller's question named them already).
        """
        if not (refused_asked or confirm_save_refused(self.window, self.state.errors)):
            return False
        path = self.state.file_path
        if path is None:
            return self._save_as()
        return self._write(path, overwrite=True)

    def save_as(self, *_: Any) -> bool:
        """Choose a file and save; an existing file is replaced only after a confirmation.

        With refused values on screen, asks first whether to save the last valid design anyway.
        """
        return confirm_save_refused(self.window, self.state.errors) and self._save_as()

    def _save_as(self) -> bool:
        suggested = str(Path(self._folder()) / f"{_slug(self.state.design.name)}.json")
        path, _filter = QFileDialog.getSaveFileName(
            self.window,
            "Save design as",
            suggested,
            DESIGN_FILTER,
            options=QFileDialog.Option.DontConfirmOverwrite,
        )
        if not path:
            return False
        target = Path(path)
        if target.suffix == "":
            target = target.with_suffix(".json")
        if target.exists() and not self._confirm_replace(target):
            return False
        return self._write(target, overwrite=target.exists())

    def _write(self, path: Path, *, overwrite: bool) -> bool:
        try:
            written = save_design(self.state.design, path, overwrite=overwrite)
        except OSError as error:
            QMessageBox.warning(self.window, "Cannot save design", write_error_text(path, error))
            return False
        self.state.mark_saved(Path(written).resolve())
        return True

    def _confirm_replace(self, path: Path) -> bool:
        answer = QMessageBox.question(
            self.window, "Replace file?", f"{path} already exists. Replace it?",
            _Buttons.Yes | _Buttons.No, _Buttons.No,
        )  # fmt: skip
        return answer == _Buttons.Yes

    def _folder(self) -> str:
        current = self.state.file_path or (self.state.recent_files[0] if self.state.recent_files else None)
        return str(current.parent) if current is not None else str(Path.home())

    # ----- exports -----

    def _export_path(self, title: str, suffix: str) -> str | None:
        suggested = str(Path(self._folder()) / f"{_slug(self.state.design.name)}_{suffix}.tif")
        path, _filter = QFileDialog.getSaveFileName(
            self.window, title, suggested, TIFF_FILTER, options=QFileDialog.Option.DontConfirmOverwrite
        )
        if not path:
            return None
        if Path(path).exists() and not self._confirm_replace(Path(path)):
            return None
        return path

    def export_psf(self, *_: Any) -> bool:
        """Write the current full PSF stack (with its design) as an ImageJ TIFF."""
        from lfm_studio.engine.io import write_psf_stack

        result = self.state.psf
        path = None if result is None else self._export_path("Export PSF stack", "psf")
        if path is None:
            return False
        self._submit_export(partial(write_psf_stack, stack=result.stack, overwrite=True), path)
        return True

    def export_image(self, *_: Any) -> bool:
        """Write the simulated light-field image (camera counts) as an ImageJ TIFF."""
        from lfm_studio.engine.io import write_image

        image = self.state.image
        path = None if image is None else self._export_path("Export light-field image", "light_field")
        if path is None:
            return False
        meta = {k: v for k, v in image.info.items() if isinstance(v, (str, int, float, type(None)))}
        write = partial(
            write_image, image=image.counts, pixel_size=image.pixel_size, metadata=meta, overwrite=True
        )
        self._submit_export(write, path)
        return True

    def export_reconstruction(self, *_: Any) -> bool:
        """Write the reconstructed volume (voxel size and depths) as an ImageJ TIFF."""
        from lfm_studio.engine.io import write_volume

        result = self.state.reconstruction
        path = None if result is None else self._export_path("Export reconstruction", "reconstruction")
        if path is None:
            return False
        psf = self.state.psf
        depths = (
            psf.stack.depths if psf is not None and len(psf.stack.depths) == result.volume.shape[0] else None
        )
        meta = {"iterations": result.iterations, "psnr_db": result.psnr, "ssim": result.ssim}
        if result.scores is not None:  # NCC and F1 first; floors and the PSNR/SSIM normalisation
            meta = {"iterations": result.iterations, **_scores_metadata(result.scores)}
        write = partial(
            write_volume, volume=result.volume, voxel_size=result.voxel_size, depths=depths, metadata=meta,
            overwrite=True,
        )  # fmt: skip
        self._submit_export(write, path)
        return True

    def _submit_export(self, write: Any, path: str) -> None:
        self.runner.submit("export", _write_tiff, write, path, on_error=partial(self._on_export_failed, path))

    def _on_export_failed(self, path: str, outcome: JobOutcome) -> None:
        error = outcome.error
        text = (
            write_error_text(path, error) if isinstance(error, OSError) else f"Cannot write {path}: {error}"
        )
        self.last_failure = show_failure(self.window, "Export failed", text, details=outcome.details or "")

    # ----- menus -----

    def _on_new_triggered(self, action: QAction) -> None:
        self.new_from_preset(action.data())

    def _on_recent_triggered(self, action: QAction) -> None:
        path = action.data()
        if path:
            self.open_file(path)

    def _on_recent_files(self, paths: tuple[Path, ...]) -> None:
        self.recent_menu.clear()
        for path in paths:
            action = self.recent_menu.addAction(path.name)
            action.setData(str(path))
            action.setToolTip(str(path))
        self.recent_menu.setEnabled(bool(paths))
        self.settings.setValue(RECENT_KEY, [str(p) for p in paths])

    def _update_exports(self, *_: Any) -> None:
        self.export_psf_action.setEnabled(self.state.psf is not None)
        self.export_image_action.setEnabled(self.state.image is not None)
        self.export_reconstruction_action.setEnabled(self.state.reconstruction is not None)

    def _on_quit(self, *_: Any) -> None:
        self.window.close()


def _scores_metadata(card: Any) -> dict[str, Any]:
    """A scorecard as flat JSON-ready metadata: each score, its zero floor, and the normalisation."""
    out: dict[str, Any] = {}
    for score in card.scores:
        entry = score.to_dict()
        out[score.key] = entry["value"]
        out[f"{score.key}_zero_floor"] = entry.get("zero_floor")
    out["normalization"] = card.normalization
    if card.peaks is not None:
        out["peaks"] = card.peaks.to_dict()
    return out
