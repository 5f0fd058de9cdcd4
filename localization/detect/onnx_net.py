"""ONNX inference for the learned detector's networks, with ONNX Runtime on the CPU.

:class:`OnnxNet` runs one exported network (no PyTorch needed). ONNX Runtime rather than
OpenCV's DNN module: it runs both networks faster on the CPU (docs/benchmarks.md). One thread by
default: the detector's latency is quoted per core, and study workers and parallel environments
each hold their own detector.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import onnxruntime as ort
from numpy.typing import ArrayLike, NDArray
from onnxruntime.capi import onnxruntime_pybind11_state as _ort_state

from localization.checks import check_number

__all__ = ["OnnxNet"]

#: What ONNX Runtime raises for a file it cannot load (its error types derive from Exception only).
_LOAD_ERRORS = tuple(
    getattr(_ort_state, name)
    for name in ("Fail", "InvalidProtobuf", "InvalidGraph", "InvalidArgument", "NoModel", "NoSuchFile",
                 "RuntimeException", "NotImplemented", "EPFail")
    if hasattr(_ort_state, name)
)


class OnnxNet:
    """One ONNX model with a single input and a first output, run on the CPU.

    Args:
        path: the ``.onnx`` file.
        threads: intra-op threads (>= 1).

    Raises:
        FileNotFoundError: if ``path`` is not a file; ValueError for a bad ``threads`` or a file
            that is not a model ONNX Runtime can load (a corrupt or truncated file), naming it.
    """

    def __init__(self, path: str | Path, threads: int = 1) -> None:
        self.path = Path(path)
        if not self.path.is_file():
            raise FileNotFoundError(f"ONNX model not found: {self.path}")
        threads = check_number("threads", threads, 1, integer=True, type_error=ValueError)
        options = ort.SessionOptions()
        options.intra_op_num_threads = threads
        options.inter_op_num_threads = 1
        options.log_severity_level = 3  # errors only
        try:
            self._session = ort.InferenceSession(
                str(self.path), sess_options=options, providers=["CPUExecutionProvider"]
            )
        except _LOAD_ERRORS as err:
            why = str(err).splitlines()[0] if str(err) else type(err).__name__
            raise ValueError(f"{str(self.path)!r} is not a model ONNX Runtime can load: {why}") from None
        self._input = self._session.get_inputs()[0].name

    def __call__(self, x: ArrayLike) -> NDArray[np.float32]:
        """The first output for input ``x`` (cast to contiguous float32)."""
        return self._session.run(None, {self._input: np.ascontiguousarray(x, dtype=np.float32)})[0]

    def __repr__(self) -> str:
        return f"OnnxNet({self.path.name!r})"
