"""Learned reconstruction trained from a design (thesis section 4.2): data, models, training, checkpoints.

Training data come from the design's own forward model (:mod:`.data`: seeded phantoms imaged
through the projector at a range of photon budgets, disjoint seeds for train, validation and
test). Three models (:mod:`.models`): unrolled Richardson-Lucy (default, a few thousand
parameters), MultiWienerNet (learnable Wiener filters per depth, then a small U-Net) and a
blind U-Net (no physics). :func:`.train.train` fits one under a time budget with validation
early stopping; :mod:`.checkpoint` stores it as safetensors with a JSON header that ties it to
the design and its sampling. The loss (:mod:`.losses`) is an energy-normalised MSE plus a
high-pass term; every prediction is checked to be neither all zero nor constant.

The thesis: J. Sun, "Computational Framework for Light-Field Microscopy Simulation and Optimization" (docs/references.md).
"""

from lfm_studio.engine.learned.checkpoint import load_model, load_model_for, read_checkpoint, save_checkpoint
from lfm_studio.engine.learned.data import TrainingDataSpec, make_sample, make_samples
from lfm_studio.engine.learned.design_setup import check_checkpoint_for_stack, stack_identity
from lfm_studio.engine.learned.models import DEFAULT_MODEL, MODELS, build_model
from lfm_studio.engine.learned.train import TrainingResult, train

__all__ = [
    "DEFAULT_MODEL",
    "MODELS",
    "TrainingDataSpec",
    "TrainingResult",
    "build_model",
    "check_checkpoint_for_stack",
    "load_model",
    "load_model_for",
    "make_sample",
    "make_samples",
    "read_checkpoint",
    "save_checkpoint",
    "stack_identity",
    "train",
]
