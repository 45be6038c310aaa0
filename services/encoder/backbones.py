"""CNN backbones f_m of Eq. 4.1, defined in plain torch with torchvision's parameter names.

Two backbones (``encoder.cnn_backbone``):

* ``shufflenetv2`` -- ShuffleNetV2 x1.0 (Ma et al. 2018), the default of Table 4.1.  The
  module tree (``conv1``, ``maxpool``, ``stage2..4``, ``conv5``, ``fc``; ``branch1`` /
  ``branch2`` inside each block) is the one of ``torchvision.models.shufflenet_v2_x1_0``,
  so a torchvision state dict loads with ``strict=True``.  The embedding is the output of
  ``stage3`` (232 channels, 14 x 14 for a 224 x 224 input), adaptive-average-pooled to a
  ``pool_grid`` x ``pool_grid`` grid and flattened: d_m = 232 * g^2 (3712 for g = 4).
  Flattening the full 232 x 14 x 14 map would give d_m = 45472 and a 186 MB projection.
* ``alexnet_conv3`` -- AlexNet (torchvision ``features.0`` .. ``features.7``, i.e. up to
  conv3 + ReLU), the encoder of NeoSLAM.  Embedding: conv3 (384 channels, 13 x 13),
  pooled to g x g: d_m = 384 * g^2 (6144 for g = 4).  A full torchvision AlexNet state
  dict loads: the keys of the layers after conv3 (``features.8`` / ``features.10``,
  ``classifier.*``) are recognised and dropped, every other key must match exactly.

Weights (:func:`load_backbone`): ``encoder.weights_path`` when set (a missing or
incompatible file is an error naming the file and the missing/unexpected keys), else the
torch hub cache (``$TORCH_HOME/hub/checkpoints`` or ``~/.cache/torch/hub/checkpoints``, with
torchvision's file names ``shufflenetv2_x1-*.pth`` or ``shufflenet_v2_x1_0-*.pth`` /
``alexnet-*.pth``), else a deterministic seeded initialisation (He-normal convolutions,
torch seed ``encoder.lsbh_seed``) with a WARNING that the embedding is untrained.
Nothing is ever downloaded.
"""
from __future__ import annotations

import glob
import logging
import os
import pickle
from dataclasses import dataclass
from pathlib import Path

import torch
from torch import nn

__all__ = [
    "ShuffleNetV2", "AlexNetConv3", "BACKBONES", "LoadedBackbone", "WeightsError",
    "build_backbone", "load_backbone", "hub_checkpoint", "load_state_dict_file",
]

log = logging.getLogger(__name__)


class WeightsError(RuntimeError):
    """A weights file that is missing, unreadable or does not fit the backbone."""


# --------------------------------------------------------------------------- ShuffleNetV2


def _channel_shuffle(x: torch.Tensor, groups: int) -> torch.Tensor:
    b, c, h, w = x.shape
    x = x.reshape(b, groups, c // groups, h, w).transpose(1, 2)
    return x.reshape(b, c, h, w)


def _depthwise(channels: int, stride: int) -> nn.Conv2d:
    return nn.Conv2d(channels, channels, 3, stride, 1, bias=False, groups=channels)


class _InvertedResidual(nn.Module):
    """ShuffleNetV2 unit: channel split (stride 1) or two-branch downsampling (stride 2)."""

    def __init__(self, inp: int, oup: int, stride: int):
        super().__init__()
        if stride not in (1, 2):
            raise ValueError(f"stride must be 1 or 2, got {stride}")
        self.stride = stride
        half = oup // 2
        if stride == 1 and inp != 2 * half:
            raise ValueError(f"stride-1 unit needs inp == oup, got {inp} -> {oup}")
        if stride > 1:
            self.branch1 = nn.Sequential(
                _depthwise(inp, stride), nn.BatchNorm2d(inp),
                nn.Conv2d(inp, half, 1, 1, 0, bias=False), nn.BatchNorm2d(half), nn.ReLU(inplace=True),
            )
        else:
            self.branch1 = nn.Sequential()
        self.branch2 = nn.Sequential(
            nn.Conv2d(inp if stride > 1 else half, half, 1, 1, 0, bias=False), nn.BatchNorm2d(half),
            nn.ReLU(inplace=True),
            _depthwise(half, stride), nn.BatchNorm2d(half),
            nn.Conv2d(half, half, 1, 1, 0, bias=False), nn.BatchNorm2d(half), nn.ReLU(inplace=True),
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if self.stride == 1:
            x1, x2 = x.chunk(2, dim=1)
            out = torch.cat((x1, self.branch2(x2)), dim=1)
        else:
            out = torch.cat((self.branch1(x), self.branch2(x)), dim=1)
        return _channel_shuffle(out, 2)


class ShuffleNetV2(nn.Module):
    """ShuffleNetV2 x1.0 with torchvision's module names; :meth:`features` stops at stage3."""

    stage_repeats = (4, 8, 4)
    stage_channels = (24, 116, 232, 464, 1024)
    embedding_channels = 232
    #: torchvision's download name (``shufflenetv2_x1-5666bf0f80.pth``) and the spelled-out form
    hub_patterns = ("shufflenetv2_x1-*.pth", "shufflenet_v2_x1_0-*.pth")

    def __init__(self, num_classes: int = 1000):
        super().__init__()
        c = self.stage_channels
        self.conv1 = nn.Sequential(nn.Conv2d(3, c[0], 3, 2, 1, bias=False), nn.BatchNorm2d(c[0]), nn.ReLU(inplace=True))
        self.maxpool = nn.MaxPool2d(kernel_size=3, stride=2, padding=1)
        inp = c[0]
        for name, repeats, oup in zip(("stage2", "stage3", "stage4"), self.stage_repeats, c[1:4]):
            units = [_InvertedResidual(inp, oup, 2)] + [_InvertedResidual(oup, oup, 1) for _ in range(repeats - 1)]
            setattr(self, name, nn.Sequential(*units))
            inp = oup
        self.conv5 = nn.Sequential(nn.Conv2d(inp, c[4], 1, 1, 0, bias=False), nn.BatchNorm2d(c[4]), nn.ReLU(inplace=True))
        self.fc = nn.Linear(c[4], num_classes)

    def features(self, x: torch.Tensor) -> torch.Tensor:
        """Intermediate block used as the embedding: the stage3 output (N, 232, H/16, W/16)."""
        return self.stage3(self.stage2(self.maxpool(self.conv1(x))))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = self.conv5(self.stage4(self.features(x)))
        return self.fc(x.mean([2, 3]))


# --------------------------------------------------------------------------- AlexNet conv3


class AlexNetConv3(nn.Module):
    """AlexNet truncated after conv3 + ReLU (torchvision ``features.0`` .. ``features.7``)."""

    embedding_channels = 384
    hub_patterns = ("alexnet-*.pth",)  # torchvision: alexnet-owt-7be5be79.pth
    #: key prefixes of a full torchvision AlexNet that belong to the dropped layers
    dropped_prefixes = ("features.8.", "features.10.", "classifier.")

    def __init__(self) -> None:
        super().__init__()
        self.features = nn.Sequential(
            nn.Conv2d(3, 64, kernel_size=11, stride=4, padding=2), nn.ReLU(inplace=True),
            nn.MaxPool2d(kernel_size=3, stride=2),
            nn.Conv2d(64, 192, kernel_size=5, padding=2), nn.ReLU(inplace=True),
            nn.MaxPool2d(kernel_size=3, stride=2),
            nn.Conv2d(192, 384, kernel_size=3, padding=1), nn.ReLU(inplace=True),
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.features(x)


BACKBONES: dict[str, type[nn.Module]] = {"shufflenetv2": ShuffleNetV2, "alexnet_conv3": AlexNetConv3}


def _feature_fn(model: nn.Module):
    return model.features if isinstance(model, ShuffleNetV2) else model.forward


def build_backbone(name: str) -> nn.Module:
    """An uninitialised-by-file backbone (torch default init from the global RNG)."""
    try:
        cls = BACKBONES[name]
    except KeyError:
        raise ValueError(f"encoder.cnn_backbone: unknown backbone {name!r}; known: {sorted(BACKBONES)}") from None
    return cls()


# --------------------------------------------------------------------------- weights


def hub_checkpoint(name: str) -> Path | None:
    """The torchvision checkpoint of backbone ``name`` in the torch hub cache, if present.

    Looks in ``$TORCH_HOME/hub/checkpoints`` (``TORCH_HOME`` default ``~/.cache/torch``);
    several matches: the lexicographically first, for determinism.
    """
    torch_home = os.environ.get("TORCH_HOME") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache"), "torch")
    folder = os.path.join(torch_home, "hub", "checkpoints")
    matches = sorted(m for pat in BACKBONES[name].hub_patterns  # type: ignore[attr-defined]
                     for m in glob.glob(os.path.join(folder, pat)))
    return Path(matches[0]) if matches else None


def load_state_dict_file(path: str | Path) -> dict[str, torch.Tensor]:
    """Read a state dict saved with ``torch.save`` (tensors only, ``weights_only``)."""
    p = Path(path)
    if not p.is_file():
        raise WeightsError(f"weights file not found: {p}")
    try:
        obj = torch.load(p, map_location="cpu", weights_only=True)
    except (RuntimeError, OSError, EOFError, ValueError, pickle.UnpicklingError) as exc:
        raise WeightsError(f"weights file {p} is not a readable torch state dict: {exc}") from exc
    if isinstance(obj, dict) and "state_dict" in obj and isinstance(obj["state_dict"], dict):
        obj = obj["state_dict"]
    if not isinstance(obj, dict) or not all(isinstance(v, torch.Tensor) for v in obj.values()):
        raise WeightsError(f"weights file {p} does not hold a state dict of tensors (got {type(obj).__name__})")
    return obj


def _apply_state_dict(model: nn.Module, state: dict[str, torch.Tensor], source: Path) -> None:
    if isinstance(model, AlexNetConv3):
        state = {k: v for k, v in state.items() if not k.startswith(AlexNetConv3.dropped_prefixes)}
    own = model.state_dict()
    missing = sorted(set(own) - set(state))
    unexpected = sorted(set(state) - set(own))
    # num_batches_tracked is optional in old torchvision checkpoints (BatchNorm fills it in)
    missing = [k for k in missing if not k.endswith("num_batches_tracked")]
    bad_shape = sorted(f"{k}: file {tuple(state[k].shape)} vs model {tuple(own[k].shape)}"
                       for k in set(own) & set(state) if state[k].shape != own[k].shape)
    if missing or unexpected or bad_shape:
        def _fmt(keys: list[str]) -> str:
            return ", ".join(keys[:8]) + (f" ... (+{len(keys) - 8} more)" if len(keys) > 8 else "")
        parts = [f"weights file {source} does not fit backbone {type(model).__name__}:"]
        if missing:
            parts.append(f"missing keys ({len(missing)}): {_fmt(missing)}")
        if unexpected:
            parts.append(f"unexpected keys ({len(unexpected)}): {_fmt(unexpected)}")
        if bad_shape:
            parts.append(f"shape mismatches ({len(bad_shape)}): {_fmt(bad_shape)}")
        raise WeightsError("\n  ".join(parts))
    model.load_state_dict(state, strict=True)


def _seeded_init(model: nn.Module) -> None:
    """He-normal (fan_out, ReLU) convolutions, zero biases, unit BatchNorm, N(0, 0.01) linear.

    PyTorch's default init shrinks ShuffleNet's activations ~1000x by stage3; He init keeps
    random features better spread (the convention of torchvision's MobileNet/ResNet).
    """
    for m in model.modules():
        if isinstance(m, nn.Conv2d):
            nn.init.kaiming_normal_(m.weight, mode="fan_out", nonlinearity="relu")
            if m.bias is not None:
                nn.init.zeros_(m.bias)
        elif isinstance(m, nn.BatchNorm2d):
            nn.init.ones_(m.weight)
            nn.init.zeros_(m.bias)
        elif isinstance(m, nn.Linear):
            nn.init.normal_(m.weight, 0.0, 0.01)
            nn.init.zeros_(m.bias)


@dataclass
class LoadedBackbone:
    """A backbone in eval mode plus where its weights came from (``seeded`` or a file path)."""

    model: nn.Module
    name: str
    weights: str
    trained: bool

    @property
    def embedding_channels(self) -> int:
        return int(self.model.embedding_channels)  # type: ignore[attr-defined]

    def features(self, x: torch.Tensor) -> torch.Tensor:
        """The intermediate block used as embedding (stage3 / conv3), un-pooled."""
        return _feature_fn(self.model)(x)


def load_backbone(name: str, weights_path: str = "", seed: int = 42) -> LoadedBackbone:
    """Build backbone ``name`` and load its weights (config path > hub cache > seeded init).

    The seeded initialisation runs under :func:`torch.random.fork_rng`, so it neither
    depends on nor disturbs the caller's global torch RNG state.
    """
    if weights_path:
        model = build_backbone(name)
        path = Path(weights_path)
        _apply_state_dict(model, load_state_dict_file(path), path)
        log.info("encoder: %s weights loaded from %s", name, path)
        return LoadedBackbone(model.eval(), name, str(path), True)
    if name not in BACKBONES:
        build_backbone(name)  # raises the clear error
    hub = hub_checkpoint(name)
    if hub is not None:
        model = build_backbone(name)
        _apply_state_dict(model, load_state_dict_file(hub), hub)
        log.info("encoder: %s weights loaded from the torch hub cache %s", name, hub)
        return LoadedBackbone(model.eval(), name, str(hub), True)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        model = build_backbone(name)
        _seeded_init(model)
    log.warning("encoder: no weights for %s (encoder.weights_path empty, none in the torch hub cache): "
                "using a seeded random initialisation (seed %d) -- the embedding is UNTRAINED", name, seed)
    return LoadedBackbone(model.eval(), name, "seeded", False)
