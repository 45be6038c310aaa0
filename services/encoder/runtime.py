"""Where the backbone f_m of Eq. 4.1 runs (``encoder.runtime``): torch, ONNX Runtime or OpenVINO.

The torch module (:mod:`services.encoder.backbones`, batch norms folded when
``encoder.fold_batchnorm``) is the definition and the reference.  For ``onnxruntime`` and
``openvino`` its :meth:`~services.encoder.backbones.LoadedBackbone.features` (the tap block,
un-pooled) is exported at start-up with :func:`torch.onnx.export` (the TorchScript exporter,
in memory, ~1 s; nothing is written or downloaded) for one image of ``input_size`` x
``input_size`` pixels, and run there in f32 (openvino: ``encoder.precision``) on
``encoder.torch_threads`` intra-op threads:

* ``onnxruntime`` -- :class:`onnxruntime.InferenceSession`, CPU provider, every graph
  optimisation, ``intra_op_num_threads`` = threads, no spinning;
* ``openvino`` -- the CPU plugin with ``INFERENCE_PRECISION_HINT`` = ``encoder.precision``:
  f32, or bf16 (what the plugin picks by itself where the processor has AVX512-BF16 or AMX:
  embeddings ~4 % off, SDRs ~97 % the same bits; on a processor without them it runs f32),
  ``INFERENCE_NUM_THREADS`` = threads, one stream, no core pinning (the other services share
  the cores).

Both take one image at a time (a static [1, 3, n, n] input: measured as fast as or faster
per image than a dynamic batch); the pooling after the tap block stays in torch, so only the
convolutions change runtime.  In f32 the same embedding as torch to ~2e-6 relative
(tests/encoder/test_runtime.py); cost: docs/DECISIONS.md, ``encoder.runtime``.
"""
from __future__ import annotations

import io
import logging
import warnings
from collections.abc import Callable
from typing import Any

import numpy as np
import torch
from torch import nn

from .backbones import LoadedBackbone

__all__ = ["RUNTIMES", "RuntimeUnavailable", "export_onnx", "make_features"]

log = logging.getLogger(__name__)

RUNTIMES = ("torch", "onnxruntime", "openvino")
ONNX_OPSET = 17

FeatureFn = Callable[[torch.Tensor], torch.Tensor]


class RuntimeUnavailable(RuntimeError):
    """The package of the configured ``encoder.runtime`` is not installed (or cannot load)."""


class _Features(nn.Module):
    """The backbone's tap-block output as a module's forward (what is exported)."""

    def __init__(self, backbone: LoadedBackbone):
        super().__init__()
        self.model = backbone.model
        self._backbone = backbone

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self._backbone.features(x)


def export_onnx(backbone: LoadedBackbone, input_size: int) -> bytes:
    """The ONNX model (bytes) of ``backbone.features`` for one (1, 3, input_size, input_size) image.

    The TorchScript exporter (``dynamo=False``) traces the module; the shape arithmetic of
    EfficientNet's "SAME" padding becomes constants for this input size (the tracer's
    warnings about it are expected and silenced), which is why the size is fixed.
    """
    try:
        import onnx  # noqa: F401  (the exporter needs it; a clear error beats its own)
    except ImportError as exc:
        raise RuntimeUnavailable("encoder.runtime: exporting the backbone needs the onnx package "
                                 "(pip install -e . installs it), or set encoder.runtime: torch") from exc
    module = _Features(backbone).eval()
    x = torch.zeros(1, 3, input_size, input_size)
    buf = io.BytesIO()
    with warnings.catch_warnings(), torch.inference_mode(False), torch.no_grad():
        warnings.simplefilter("ignore", torch.jit.TracerWarning)  # type: ignore[attr-defined]
        warnings.filterwarnings("ignore", message="Constant folding", category=UserWarning)
        # torch >= 2.9 calls the TorchScript exporter legacy; it is the one that needs no onnxscript
        warnings.filterwarnings("ignore", category=DeprecationWarning, module=r"torch\.onnx")
        warnings.filterwarnings("ignore", message=".*legacy TorchScript-based ONNX export", category=DeprecationWarning)
        torch.onnx.export(module, (x,), buf,  # type: ignore[arg-type]  # a file-like target works; the stubs say path
                          dynamo=False, input_names=["x"], output_names=["y"], opset_version=ONNX_OPSET,
                          do_constant_folding=True)
    return buf.getvalue()


def _stacked(run_one: Callable[[np.ndarray], np.ndarray]) -> FeatureFn:
    """A feature function running ``run_one`` on each (1, 3, n, n) image of a batch."""

    def features(x: torch.Tensor) -> torch.Tensor:
        a = np.ascontiguousarray(x.detach().contiguous().numpy(), dtype=np.float32)
        outs = [run_one(a[i:i + 1]) for i in range(a.shape[0])]
        return torch.from_numpy(np.concatenate(outs, axis=0))

    return features


def _onnxruntime(model: bytes, threads: int) -> FeatureFn:
    try:
        import onnxruntime as ort
    except ImportError as exc:
        raise RuntimeUnavailable("encoder.runtime onnxruntime: the onnxruntime package is not installed "
                                 "(pip install -e . installs it), or set encoder.runtime: torch") from exc
    so = ort.SessionOptions()
    so.intra_op_num_threads = threads
    so.inter_op_num_threads = 1
    so.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    so.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    so.add_session_config_entry("session.intra_op.allow_spinning", "0")
    so.log_severity_level = 3
    sess = ort.InferenceSession(model, so, providers=["CPUExecutionProvider"])
    name = sess.get_inputs()[0].name

    def run_one(a: np.ndarray) -> np.ndarray:
        out: np.ndarray = sess.run(None, {name: a})[0]
        return out

    return _stacked(run_one)


def _openvino(model: bytes, threads: int, precision: str = "f32") -> FeatureFn:
    try:
        import openvino as ov
    except ImportError as exc:
        raise RuntimeUnavailable("encoder.runtime openvino: the openvino package is not installed "
                                 "(pip install -e . installs it), or set encoder.runtime: torch") from exc
    core = ov.Core()
    ov_model: Any = core.read_model(model)  # ONNX bytes: the ONNX frontend, in memory
    compiled = core.compile_model(ov_model, "CPU", {
        "INFERENCE_PRECISION_HINT": precision, "INFERENCE_NUM_THREADS": threads, "NUM_STREAMS": 1,
        "ENABLE_CPU_PINNING": False, "PERFORMANCE_HINT": "LATENCY"})
    request = compiled.create_infer_request()
    output = request.get_output_tensor(0)

    def run_one(a: np.ndarray) -> np.ndarray:
        # the image as the request's input tensor without a copy, and the output read from the
        # request's own tensor: the same values as infer({0: a}), without the Python dispatch
        # of its input dict and output map (~0.3 of ~2 ms per image: docs/DECISIONS.md, encoder.runtime)
        request.set_input_tensor(ov.Tensor(np.ascontiguousarray(a, dtype=np.float32), shared_memory=True))
        request.infer()
        out: np.ndarray = np.array(output.data, dtype=np.float32, copy=True)  # the next infer overwrites it
        return out

    return _stacked(run_one)


def make_features(backbone: LoadedBackbone, runtime: str, input_size: int, threads: int,
                  precision: str = "f32") -> FeatureFn:
    """The function (N, 3, n, n) float32 batch -> (N, C, h, w) tap-block output that runs
    ``backbone`` on ``runtime`` (``torch``: the module itself); ``precision`` (``encoder.precision``)
    f32, or bf16 on openvino only."""
    if precision not in ("f32", "bf16") or (precision == "bf16" and runtime != "openvino"):
        raise ValueError(f"encoder.precision {precision!r} with encoder.runtime {runtime!r}: "
                         f"bf16 runs on openvino only, everything runs f32")
    if runtime == "torch":
        return backbone.features
    if runtime not in RUNTIMES:
        raise ValueError(f"encoder.runtime: unknown runtime {runtime!r}; known: {list(RUNTIMES)}")
    if runtime == "onnxruntime":
        try:
            import onnxruntime  # noqa: F401
        except ImportError as exc:
            raise RuntimeUnavailable("encoder.runtime onnxruntime: the onnxruntime package is not installed "
                                     "(pip install -e . installs it), or set encoder.runtime: torch") from exc
    model = export_onnx(backbone, input_size)
    fn = _onnxruntime(model, threads) if runtime == "onnxruntime" else _openvino(model, threads, precision)
    log.debug("encoder: %s backbone exported to ONNX (%d bytes, %d px) and compiled for %s %s, %d thread(s)",
              backbone.name, len(model), input_size, runtime, precision, threads)
    return fn
