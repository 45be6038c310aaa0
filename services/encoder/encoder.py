"""The multimodal encoder of the neocortical front-end (Eqs. 4.1-4.3), without transport.

Per modality m: y = f_m(o) (Eq. 4.1, :mod:`services.encoder.backbones`: the tap block of
EfficientNet-Lite0 (default block 10) or ShuffleNetV2 stage3 / AlexNet conv3, pooled to
``pool_grid`` x ``pool_grid`` and flattened), z = standardised y
(``encoder.embedding_norm.mode``, :mod:`services.encoder.standardize`; ``none``: z = y),
s^(m) = LSBH(P_m^T z) (Eq. 4.2, :mod:`services.encoder.lsbh`), fused by OR (Eq. 4.3,
:mod:`services.encoder.fusion`).
Camera and sonar share one backbone (the sonar raster is replicated to 3 channels) and have
separate projections P_camera, P_sonar.

Pre-processing: RGB in [0, 1], resized to ``input_size`` x ``input_size`` with bilinear
:func:`torch.nn.functional.interpolate` (antialiased when shrinking), ImageNet mean/std
normalisation.  Inference: CPU, ``torch.set_num_threads(encoder.torch_threads)``,
batch norms folded into their convolutions (``encoder.fold_batchnorm``), channels_last, :func:`torch.inference_mode`, batches of up to ``encoder.batch_max`` frames.
The backbone runs on ``encoder.runtime`` (:mod:`services.encoder.runtime`: torch, or the same
module exported to ONNX Runtime / OpenVINO at start-up); pooling and everything after it in torch/numpy.
"""
from __future__ import annotations

import dataclasses
import hashlib
import logging
from collections.abc import Mapping, Sequence

import numpy as np
import torch
import torch.nn.functional as F

from services.encoder.config import EncoderConfig

from .backbones import LoadedBackbone, fold_batchnorm, load_backbone
from .fusion import fuse as fuse_sdrs
from .images import image_to_rgb
from .lsbh import LsbhEncoder, load_or_create_projection, projection_path
from .runtime import make_features
from .standardize import EmbeddingStandardizer, norm_path

__all__ = ["MultimodalEncoder", "image_to_rgb", "INPUT_SIZE", "IMAGENET_MEAN", "IMAGENET_STD"]

log = logging.getLogger(__name__)

INPUT_SIZE = 224  # the dissertation's input; encoder.input_size sets the one used
IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)


class MultimodalEncoder:
    """Backbone + per-modality LSBH + fusion, configured by the ``encoder`` section.

    ``images`` passed to :meth:`embed` are (H, W, 3) RGB (uint8 0-255, or float in [0, 1]) or
    (H, W) grey arrays of any size.  ``channels_last`` False is only for benchmarking.
    ``runtime`` (default ``cfg.runtime``) picks where the backbone runs; :attr:`model` is always
    the torch module (the reference).
    """

    def __init__(self, cfg: EncoderConfig, backbone: LoadedBackbone | None = None, channels_last: bool = True,
                 runtime: str | None = None):
        self.cfg = cfg
        torch.set_num_threads(cfg.torch_threads)
        self.backbone = backbone if backbone is not None else load_backbone(
            cfg.cnn_backbone, cfg.weights_path, seed=cfg.lsbh.seed, untrained=cfg.untrained, tap_block=cfg.tap_block)
        self.input_size = int(cfg.input_size)
        self.runtime = runtime or cfg.runtime
        # the exported runtimes take plain NCHW arrays; channels_last only helps torch's kernels
        channels_last = channels_last and self.runtime == "torch"
        self.channels_last = channels_last
        self.memory_format = torch.channels_last if channels_last else torch.contiguous_format
        if cfg.fold_batchnorm:
            self.backbone = dataclasses.replace(self.backbone, model=fold_batchnorm(self.backbone.model))
        # torch's Module.to stubs omit the memory_format keyword the method accepts
        self.model = self.backbone.model.eval().to(memory_format=self.memory_format)  # type: ignore[call-overload]
        self.dim = self.backbone.embedding_channels * cfg.pool_grid ** 2
        # encoder.precision applies to openvino only (a runtime override to torch/onnxruntime runs f32)
        self.precision = cfg.precision if self.runtime == "openvino" else "f32"
        self._features = make_features(self.backbone, self.runtime, self.input_size, cfg.torch_threads,
                                       self.precision)
        self._mean = torch.tensor(IMAGENET_MEAN, dtype=torch.float32).view(1, 3, 1, 1)
        self._std = torch.tensor(IMAGENET_STD, dtype=torch.float32).view(1, 3, 1, 1)
        self._lsbh: dict[str, LsbhEncoder] = {}
        self._norm: dict[str, EmbeddingStandardizer] = {}
        self._digests: dict[str, str] = {}

    @property
    def weights(self) -> str:
        """``seeded`` or the weights file used."""
        return self.backbone.weights

    # ------------------------------------------------------------------ Eq. 4.1
    def _to_tensor(self, img: np.ndarray) -> torch.Tensor:
        a = np.asarray(img)
        if a.ndim == 2:
            a = a[:, :, None].repeat(3, axis=2)
        if a.ndim != 3 or a.shape[2] not in (3, 4):
            raise ValueError(f"encoder: image must be (H, W), (H, W, 3) or (H, W, 4), got shape {a.shape}")
        a = a[:, :, :3]
        t = torch.from_numpy(np.array(a, copy=True, order="C")).permute(2, 0, 1).unsqueeze(0)
        is_u8 = t.dtype == torch.uint8
        if not is_u8:
            t = t.float()
        h, w = t.shape[2:]
        n = self.input_size
        if (h, w) != (n, n):
            # uint8 frames are resized as uint8 (torch's fast path, ~30x faster than float)
            shrink = h > n or w > n
            t = F.interpolate(t, size=(n, n), mode="bilinear", align_corners=False,
                              antialias=shrink)
        if is_u8:
            t = t.float() / 255.0
        return t

    def preprocess(self, images: Sequence[np.ndarray]) -> torch.Tensor:
        """(N, 3, input_size, input_size) normalised batch in the encoder's memory format."""
        batch = torch.cat([self._to_tensor(im) for im in images], dim=0)
        batch = (batch - self._mean) / self._std
        return batch.contiguous(memory_format=self.memory_format)

    def embed(self, images: Sequence[np.ndarray]) -> list[np.ndarray]:
        """Embeddings y (float32, d_m each) of ``images``, run in batches of ``batch_max``."""
        out: list[np.ndarray] = []
        g = self.cfg.pool_grid
        for i in range(0, len(images), self.cfg.batch_max):
            x = self.preprocess(images[i:i + self.cfg.batch_max])
            with torch.inference_mode():
                f = self._features(x)
                f = F.adaptive_avg_pool2d(f, g).reshape(f.shape[0], -1)
            out.extend(np.ascontiguousarray(r, dtype=np.float32) for r in f.numpy())
        return out

    def encode_camera(self, images: Sequence[np.ndarray]) -> list[np.ndarray]:
        """Camera embeddings y^(cam) (Eq. 4.1)."""
        return self.embed(images)

    def encode_sonar(self, rasters: Sequence[np.ndarray]) -> list[np.ndarray]:
        """Sonar embeddings y^(son) of rasters from :class:`~services.encoder.sonar.SonarRaster` (Eq. 4.1)."""
        return self.embed(rasters)

    # ------------------------------------------------------------------ Eq. 4.2
    def lsbh(self, modality: str) -> LsbhEncoder:
        """The LSBH of ``modality`` (projection loaded from / saved to ``lsbh.matrix_path``)."""
        enc = self._lsbh.get(modality)
        if enc is None:
            path = None
            if self.cfg.lsbh.matrix_path:
                path = projection_path(self.cfg.lsbh.matrix_path, self.cfg.cnn_backbone, modality)
            p = load_or_create_projection(path, self.dim, self.cfg.sp_columns // 2, self.cfg.lsbh.seed, modality)
            enc = self._lsbh[modality] = LsbhEncoder(p, self.cfg.sp_columns, self.cfg.lsbh.s)
        return enc

    def standardizer(self, modality: str) -> EmbeddingStandardizer:
        """The embedding standardiser of ``modality`` (statistics at ``embedding_norm.path``)."""
        st = self._norm.get(modality)
        if st is None:
            c = self.cfg
            path = norm_path(c.embedding_norm.path, c.cnn_backbone, modality) if c.embedding_norm.path else None
            st = self._norm[modality] = EmbeddingStandardizer(self.dim, c.embedding_norm.mode, c.embedding_norm.warmup,
                                                             c.embedding_norm.rate, c.embedding_norm.scale, path)
        return st

    @property
    def standardizers(self) -> dict[str, EmbeddingStandardizer]:
        """The standardisers created so far, by modality (a new dict; the objects are the encoder's)."""
        return dict(self._norm)

    def lsbh_digests(self) -> dict[str, str]:
        """sha256 (hex) of each LSBH projection created so far, by modality: identifies P_m
        without storing it (the projections are rebuilt from the seed or their file)."""
        for m, e in self._lsbh.items():
            if m not in self._digests:
                self._digests[m] = hashlib.sha256(np.ascontiguousarray(e.projection).tobytes()).hexdigest()
        return dict(self._digests)

    def set_standardizer(self, modality: str, st: EmbeddingStandardizer) -> None:
        """Use ``st`` for ``modality`` (e.g. statistics fitted on a reference set)."""
        if st.dim != self.dim:
            raise ValueError(f"standardiser has {st.dim} dimensions, the encoder {self.dim}")
        self._norm[modality] = st

    def standardize(self, modality: str, embedding: np.ndarray, update: bool = True) -> np.ndarray:
        """z of one embedding of ``modality``; ``running`` statistics take the frame in unless ``update`` False."""
        return self.standardizer(modality).transform(embedding, update)

    def settled(self, modality: str, frames: int) -> bool:
        """The statistics of ``modality`` hold ``frames`` embeddings or are not estimated online."""
        return self.standardizer(modality).settled(frames)

    def sdr(self, modality: str, embedding: np.ndarray, update: bool = True) -> np.ndarray:
        """Sorted uint32 active bits (2k of L) of one embedding of ``modality`` (Eq. 4.2 on z)."""
        return self.lsbh(modality).encode(self.standardize(modality, embedding, update))

    def standardize_sequence(self, modality: str, embeddings: Sequence[np.ndarray]) -> list[np.ndarray]:
        """z of each embedding of one modality's sequence, as the encoder node gives them: with
        the warm-up hold (``embedding_norm.hold``, :mod:`services.encoder.core`) the embeddings
        before the statistics settle are standardised with the statistics at that point."""
        c = self.cfg
        hold = c.embedding_norm.hold if c.embedding_norm.mode == "running" else 0
        out: list[np.ndarray] = []
        pending: list[np.ndarray] = []
        holding = hold > 0 and not self.settled(modality, hold)
        for y in embeddings:
            if not holding:
                out.append(self.standardize(modality, y))
                continue
            self.standardize(modality, y)
            pending.append(y)
            if self.settled(modality, hold) or len(pending) >= c.embedding_norm.warmup:
                out.extend(self.standardize(modality, p, update=False) for p in pending)
                pending, holding = [], False
        out.extend(self.standardize(modality, p, update=False) for p in pending)
        return out

    def sdr_batch(self, modality: str, embeddings: Sequence[np.ndarray], update: bool = True) -> list[np.ndarray]:
        """:meth:`sdr` of each embedding, in order (the running statistics advance frame by frame)."""
        return [self.sdr(modality, y, update) for y in embeddings]

    def close(self) -> None:
        """Persist the standardisation statistics that changed."""
        for st in self._norm.values():
            st.close()

    # ------------------------------------------------------------------ Eq. 4.3
    def fuse(self, sdrs: Mapping[str, np.ndarray | None], mode: str | None = None) -> np.ndarray:
        """Fused active bits of the modalities present (``encoder.fusion_mode`` unless ``mode``)."""
        return fuse_sdrs(sdrs, mode or self.cfg.fusion_mode)
