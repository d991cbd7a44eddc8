"""The optimiser (thesis chapter 5): design spaces, constraints, objectives, grid search and studies.

Example::

    from lfm_studio.engine.optimize import DesignSpace, Evaluator, Parameter, grid_search, objective_named

    space = DesignSpace((Parameter("objective.numerical_aperture", 0.5, 1.0, step=0.1),))
    evaluator = Evaluator(design, space, [objective_named("lateral_resolution")])
    result = grid_search(evaluator)                     # every grid point, in process
    result.best.params, result.best.values

    from lfm_studio.engine.optimize.study import run_study   # Optuna (SQLite by default), resumable
    study = run_study(evaluator, "sqlite:///study.db", sampler="grid")

:mod:`.study` needs Optuna (``pip install "lfm-studio[optimize]"``); the rest does not.

MLA layouts: :func:`.algorithm2.algorithm2` (the thesis' Algorithm 2, greedy cell merges on the
:class:`.mla_cells.MLAPlane`; :func:`.algorithm2_study.run_algorithm2_study` records it into the
same resumable study format) and :func:`.algorithm1.concatenate` (Algorithm 1, the MLA phase
mask from a lenslet list). PSF-engineering losses of section 5.2.2 (:mod:`.psf_losses`):
:func:`.psf_losses.depth_dissimilarity`, :func:`.psf_losses.mtf_support`,
:func:`.psf_losses.axial_crb`, also the named objectives ``axial_crb`` (um),
``depth_dissimilarity`` and ``mtf_support``.

Gradient optimisation (:mod:`.gradient`): :func:`.gradient.optimize_psf` descends a PSF loss
through the differentiable Fourier fast path or conventional patterns (Adam / L-BFGS, bounds
projected after each step, a float32-float64 gradient check, each step a study trial); :func:`.end_to_end.optimize_end_to_end`
trains the optics and an unrolled-RL reconstruction jointly on a task loss (either side frozen on request).

The thesis: J. Sun, "Computational Framework for Light-Field Microscopy Simulation and Optimization" (docs/references.md).
"""

from lfm_studio.engine.design.space import DesignSpace, Parameter, load_space, space_from_json
from lfm_studio.engine.optimize import task_score as _task_score  # noqa: F401  (registers task_* objectives)
from lfm_studio.engine.optimize.algorithm2 import Algorithm2Result, LayoutTrial, algorithm2
from lfm_studio.engine.optimize.algorithm2_study import run_algorithm2_study
from lfm_studio.engine.optimize.candidate import Candidate, EvaluationSettings
from lfm_studio.engine.optimize.constraints import (
    DEFAULT_CONSTRAINTS,
    FocalLengthCatalogue,
    Infeasible,
    InsidePupil,
    MinimumLensletSize,
    NoSubImageOverlap,
    SubImagesOnSensor,
)
from lfm_studio.engine.optimize.crop import auto_crop, crop_views
from lfm_studio.engine.optimize.end_to_end import optimize_end_to_end
from lfm_studio.engine.optimize.evaluate import EvaluationRecord, Evaluator
from lfm_studio.engine.optimize.gradient import GradientResult, optimize_psf
from lfm_studio.engine.optimize.gradient_params import DIFFERENTIABLE_PATHS, NotDifferentiableError
from lfm_studio.engine.optimize.grid_search import SearchResult, best_of, grid_search
from lfm_studio.engine.optimize.mla_cells import MLAPlane
from lfm_studio.engine.optimize.objectives import (
    ClosedForm,
    Objective,
    PSFLoss,
    RequirementsConstraint,
    RequirementsPenalty,
    WeightedSum,
    objective_named,
    objective_names,
    register_objective,
)
from lfm_studio.engine.optimize.psf_losses import axial_crb, depth_dissimilarity, mtf_support
from lfm_studio.engine.optimize.task_score import TaskFloorWarning, TaskScore, score_volume

__all__ = [
    "DEFAULT_CONSTRAINTS",
    "DIFFERENTIABLE_PATHS",
    "Algorithm2Result",
    "Candidate",
    "ClosedForm",
    "DesignSpace",
    "EvaluationRecord",
    "EvaluationSettings",
    "Evaluator",
    "FocalLengthCatalogue",
    "GradientResult",
    "Infeasible",
    "InsidePupil",
    "LayoutTrial",
    "MLAPlane",
    "MinimumLensletSize",
    "NoSubImageOverlap",
    "NotDifferentiableError",
    "Objective",
    "PSFLoss",
    "Parameter",
    "RequirementsConstraint",
    "RequirementsPenalty",
    "SearchResult",
    "SubImagesOnSensor",
    "TaskFloorWarning",
    "TaskScore",
    "WeightedSum",
    "algorithm2",
    "auto_crop",
    "axial_crb",
    "best_of",
    "crop_views",
    "depth_dissimilarity",
    "grid_search",
    "load_space",
    "mtf_support",
    "objective_named",
    "objective_names",
    "optimize_end_to_end",
    "optimize_psf",
    "register_objective",
    "run_algorithm2_study",
    "score_volume",
    "space_from_json",
]
