"""Learned reconstruction trained from a design (thesis section 4.2): data, models, training, checkpoints.

Training data come from the design's own forward model (:mod:`.data`: seeded phantoms imaged
through the projector at a range of photon budgets, disjoint seeds for train, validation and
test). Three models (:mod:`.models`): unrolled Richardson-Lucy (default, a few thousand
parameters), MultiWienerNet (learnable Wiener filters per depth, then a small U-Net) and a
blind U-Net (no physics). :func:`.train.train` fits one under a time budget with validation
early stopping; :mod:`.checkpoint` stores it as safetensors with a JSON header that ties it to
the design and its sampling. The loss (:mod:`.losses`) is an energy-normalised MSE plus a
high-pass term; every prediction is checked to be neither all zero nor constant.
"""
