"""Designs: typed, validated, versioned descriptions of light-field microscopes.

A :class:`Design` composes frozen pydantic specs of its parts (objective, relay
lens, MLA, camera, depths, accuracy) whose fields carry their units in their names
(``wavelength_nm``, ``pitch_um``, ``focal_length_mm``) and expose SI values as
properties. Physics invariants are checked at construction (errors name the
parameter, its value with unit, and a fix; questionable choices emit a
:class:`DesignWarning`). Designs are changed with :meth:`Design.updated` /
:func:`evolve`, hashed with :func:`spec_hash`, saved as human-readable JSON with
:func:`save_design` and read back (older schema versions migrated) with
:func:`load_design`; bundled presets come from :func:`load_preset`.
"""

from lfm_studio.engine.design.accuracy import (
    ACCURACY_PRESETS,
    PRESET_ERROR_BOUNDS,
    AccuracySpec,
    describe_preset,
)
from lfm_studio.engine.design.camera import CameraSpec
from lfm_studio.engine.design.depths import DepthSpec
from lfm_studio.engine.design.design import METADATA_FIELDS, SCHEMA_VERSION, Design
from lfm_studio.engine.design.design_io import design_from_json, design_to_json, load_design, save_design
from lfm_studio.engine.design.errors import DesignError, DesignFileError, DesignWarning
from lfm_studio.engine.design.evolve import evolve
from lfm_studio.engine.design.hashing import canonical_json, lenslet_hashes, optics_hash, spec_hash
from lfm_studio.engine.design.lenslet import LensletSpec
from lfm_studio.engine.design.migrations import MIGRATIONS, register_migration
from lfm_studio.engine.design.mla import LATTICES, AnyMLASpec, MLASpec, RegularMLASpec
from lfm_studio.engine.design.objective import ObjectiveSpec, RelayLensSpec
from lfm_studio.engine.design.presets import list_presets, load_preset, resolve_design
from lfm_studio.engine.design.pupil_phase import PupilPhaseSpec

__all__ = [
    "ACCURACY_PRESETS",
    "LATTICES",
    "METADATA_FIELDS",
    "MIGRATIONS",
    "PRESET_ERROR_BOUNDS",
    "SCHEMA_VERSION",
    "AccuracySpec",
    "AnyMLASpec",
    "CameraSpec",
    "DepthSpec",
    "Design",
    "DesignError",
    "DesignFileError",
    "DesignWarning",
    "LensletSpec",
    "MLASpec",
    "ObjectiveSpec",
    "PupilPhaseSpec",
    "RegularMLASpec",
    "RelayLensSpec",
    "canonical_json",
    "describe_preset",
    "design_from_json",
    "design_to_json",
    "evolve",
    "lenslet_hashes",
    "list_presets",
    "load_design",
    "load_preset",
    "optics_hash",
    "register_migration",
    "resolve_design",
    "save_design",
    "spec_hash",
]
