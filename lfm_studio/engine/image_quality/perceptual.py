"""LPIPS (Zhang et al. 2018, learned perceptual similarity), only from locally installed weights.

LPIPS needs the ``lpips`` package (which ships its linear-layer weights), torchvision
and the ImageNet backbone checkpoint in torch's hub cache
(``torch.hub.get_dir()/checkpoints``). Nothing is downloaded at run time: the backbone
is built without weights and its checkpoint is loaded from that folder, and when
anything is missing :class:`LPIPSUnavailableError` says what and where.

Volumes are scored slice by slice (each z slice a grey image repeated on the three
colour channels, mapped to ``[-1, 1]`` with the truth's minimum and the data range)
and the slice scores averaged; lower is more similar.
"""

from __future__ import annotations

import importlib
import importlib.util
from pathlib import Path

import torch

from lfm_studio.engine.image_quality.basic import as_pair, data_range_of

BACKBONE_CHECKPOINTS = {
    "alex": "alexnet-owt-7be5be79.pth",
    "vgg": "vgg16-397923af.pth",
    "squeeze": "squeezenet1_1-b8a52dc0.pth",
}
"""torchvision's ImageNet checkpoint file of each LPIPS backbone (looked up in the torch hub cache)."""
_TORCHVISION_MODELS = {"alex": "alexnet", "vgg": "vgg16", "squeeze": "squeezenet1_1"}


class LPIPSUnavailableError(RuntimeError):
    """LPIPS cannot run here: a package or its network weights are not installed locally."""


def _find(name: str):
    try:
        return importlib.util.find_spec(name)
    except (ImportError, ValueError):
        return None


def _weight_files(net: str) -> tuple[Path | None, Path]:
    """(the lpips linear weights file or None, the backbone checkpoint path)."""
    spec = _find("lpips")
    linear = None
    if spec is not None and spec.submodule_search_locations:
        linear = Path(next(iter(spec.submodule_search_locations))) / "weights" / "v0.1" / f"{net}.pth"
    return linear, Path(torch.hub.get_dir()) / "checkpoints" / BACKBONE_CHECKPOINTS[net]


def lpips_available(net: str = "alex") -> tuple[bool, str]:
    """``(True, "")`` when LPIPS with backbone ``net`` can run offline, else ``(False, reason and fix)``."""
    if net not in BACKBONE_CHECKPOINTS:
        raise ValueError(f"net must be one of {tuple(BACKBONE_CHECKPOINTS)}; got {net!r}.")
    missing = [name for name in ("lpips", "torchvision") if _find(name) is None]
    if missing:
        return False, (
            f"LPIPS needs the Python package(s) {', '.join(missing)}, which are not installed; nothing is "
            "downloaded at run time. Fix: install them (pip install lpips torchvision) and put the "
            f"{BACKBONE_CHECKPOINTS[net]} checkpoint in {Path(torch.hub.get_dir()) / 'checkpoints'}, "
            "or leave LPIPS out."
        )
    linear, backbone = _weight_files(net)
    absent = [str(path) for path in (linear, backbone) if path is None or not path.is_file()]
    if absent:
        return False, (
            f"LPIPS ({net}) needs network weights that are not present locally: {', '.join(absent)}; "
            "nothing is downloaded at run time. Fix: copy the weight files there (the lpips package "
            "ships its linear weights; the backbone is torchvision's ImageNet checkpoint), or leave LPIPS out."
        )
    return True, ""


def _model(net: str, device: torch.device) -> torch.nn.Module:
    lpips_module = importlib.import_module("lpips")
    models = importlib.import_module("torchvision.models")
    _, backbone_path = _weight_files(net)
    # pnet_rand=True: build the backbone without asking torchvision for (downloaded) weights.
    model = lpips_module.LPIPS(net=net, pretrained=True, pnet_rand=True, verbose=False)
    reference = getattr(models, _TORCHVISION_MODELS[net])(weights=None)
    reference.load_state_dict(torch.load(backbone_path, map_location="cpu", weights_only=True))
    for block in model.net.children():  # slice1..sliceN hold features[i] under the name "i"
        for index, layer in block.named_children():
            layer.load_state_dict(reference.features[int(index)].state_dict())
    return model.eval().to(device)


def lpips(truth, estimate, *, data_range: float | None = None, net: str = "alex") -> torch.Tensor:
    """Mean LPIPS distance of ``estimate`` to ``truth`` (images ``(Y, X)`` or volumes ``(Z, Y, X)``).

    Raises :class:`LPIPSUnavailableError` (with what is missing and where it is looked
    for) unless the package, torchvision and the weights are installed locally.
    """
    ok, reason = lpips_available(net)
    if not ok:
        raise LPIPSUnavailableError(reason)
    truth, estimate = as_pair(truth, estimate, name="lpips")
    r = data_range_of(truth, data_range)
    low = truth.min()
    slices = [t if t.ndim == 3 else t[None] for t in (truth, estimate)]
    images = [(2.0 * (s - low) / r - 1.0).float()[:, None].expand(-1, 3, -1, -1) for s in slices]
    model = _model(net, truth.device)
    with torch.no_grad():
        return model(images[0], images[1]).double().mean()
