"""A minimal TFLite interpreter over the C library bundled in the pyopen-wakeword wheel (ctypes, numpy only).

Only what a float32 model with one input and one output needs: resize the input, invoke, read the output.
The library is found inside the installed wheel; nothing is ever downloaded.
"""

import ctypes
import os
from functools import lru_cache
from importlib.util import find_spec
from pathlib import Path

import numpy as np

WHEEL = "pyopen_wakeword"
WHEEL_PIN = "pyopen-wakeword==1.1.0"
_int32 = ctypes.c_int32
_pointer = ctypes.c_void_p
_size = ctypes.c_size_t

# (name, argument types, result type) of every C function used
_SIGNATURES = (
    ("TfLiteModelCreateFromFile", [ctypes.c_char_p], _pointer),
    ("TfLiteInterpreterOptionsCreate", [], _pointer),
    ("TfLiteInterpreterOptionsSetNumThreads", [_pointer, _int32], None),
    ("TfLiteInterpreterOptionsDelete", [_pointer], None),
    ("TfLiteInterpreterOptionsAddDelegate", [_pointer, _pointer], None),
    ("TfLiteXNNPackDelegateCreate", [_pointer], _pointer),
    ("TfLiteInterpreterCreate", [_pointer, _pointer], _pointer),
    ("TfLiteInterpreterResizeInputTensor", [_pointer, _int32, ctypes.POINTER(_int32), _int32], ctypes.c_int),
    ("TfLiteInterpreterAllocateTensors", [_pointer], ctypes.c_int),
    ("TfLiteInterpreterInvoke", [_pointer], ctypes.c_int),
    ("TfLiteInterpreterGetInputTensor", [_pointer, _int32], _pointer),
    ("TfLiteInterpreterGetOutputTensor", [_pointer, _int32], _pointer),
    ("TfLiteTensorNumDims", [_pointer], _int32),
    ("TfLiteTensorDim", [_pointer, _int32], _int32),
    ("TfLiteTensorCopyFromBuffer", [_pointer, _pointer, _size], ctypes.c_int),
    ("TfLiteTensorCopyToBuffer", [_pointer, _pointer, _size], ctypes.c_int),
    ("TfLiteTensorByteSize", [_pointer], _size),
)


class FrontEndUnavailable(RuntimeError):
    """The wheel that ships the front end's models and runtime is not installed (or is damaged)."""


def wheel_folder() -> Path:
    """The installed pyopen_wakeword package folder, found without importing it."""
    spec = find_spec(WHEEL)
    if spec is None or not spec.submodule_search_locations:
        raise FrontEndUnavailable(
            f"The speech-embedding front end needs the {WHEEL_PIN} wheel: `pip install '{WHEEL_PIN}'`."
        )
    return Path(next(iter(spec.submodule_search_locations)))


def wheel_file(*parts: str) -> Path:
    path = wheel_folder().joinpath(*parts)
    if not path.is_file():
        raise FrontEndUnavailable(f"{path} is missing: reinstall '{WHEEL_PIN}'.")
    return path


@lru_cache(maxsize=1)
def library() -> ctypes.CDLL:
    lib = ctypes.CDLL(str(wheel_file("lib", "libtensorflowlite_c.so")), mode=os.RTLD_LOCAL)
    for name, arguments, result in _SIGNATURES:
        function = getattr(lib, name)
        function.argtypes, function.restype = arguments, result
    return lib


class Interpreter:
    """One float32 TFLite model with one input and one output, run on `threads` threads with the XNNPACK
    kernels (about 3× faster than the reference kernels for the embedding model)."""

    def __init__(self, model_path: Path, threads: int = 1) -> None:
        self.lib = library()
        self.name = model_path.name
        self.model = self.lib.TfLiteModelCreateFromFile(str(model_path).encode())
        if not self.model:
            raise FrontEndUnavailable(f"TFLite could not read {model_path}: reinstall '{WHEEL_PIN}'.")
        options = self.lib.TfLiteInterpreterOptionsCreate()
        self.lib.TfLiteInterpreterOptionsSetNumThreads(options, threads)
        # NULL options: XNNPACK's defaults. Kept for the interpreter's lifetime (one per process).
        self.delegate = self.lib.TfLiteXNNPackDelegateCreate(None)
        self.lib.TfLiteInterpreterOptionsAddDelegate(options, self.delegate)
        self.interpreter = self.lib.TfLiteInterpreterCreate(self.model, options)
        self.lib.TfLiteInterpreterOptionsDelete(options)
        self.input_shape: tuple[int, ...] = ()

    def run(self, inputs: np.ndarray) -> np.ndarray:
        """The model's output for float32 `inputs` of any shape the model accepts, shaped as it says."""
        inputs = np.ascontiguousarray(inputs, dtype=np.float32)
        if inputs.shape != self.input_shape:
            self._resize(inputs.shape)
        tensor = self.lib.TfLiteInterpreterGetInputTensor(self.interpreter, 0)
        self._check(self.lib.TfLiteTensorCopyFromBuffer(tensor, inputs.ctypes.data, inputs.nbytes), "copy in")
        self._check(self.lib.TfLiteInterpreterInvoke(self.interpreter), "invoke")
        output = self.lib.TfLiteInterpreterGetOutputTensor(self.interpreter, 0)
        shape = [self.lib.TfLiteTensorDim(output, i) for i in range(self.lib.TfLiteTensorNumDims(output))]
        result = np.empty(shape, dtype=np.float32)
        if result.nbytes != self.lib.TfLiteTensorByteSize(output):
            raise RuntimeError(f"{self.name}: the output is not float32 shaped {shape}.")
        self._check(self.lib.TfLiteTensorCopyToBuffer(output, result.ctypes.data, result.nbytes), "copy out")
        return result

    def _resize(self, shape: tuple[int, ...]) -> None:
        dims = (_int32 * len(shape))(*shape)
        status = self.lib.TfLiteInterpreterResizeInputTensor(self.interpreter, 0, dims, len(shape))
        self._check(status, "resize")
        self._check(self.lib.TfLiteInterpreterAllocateTensors(self.interpreter), "allocate")
        self.input_shape = shape

    def _check(self, status: int, step: str) -> None:
        if status != 0:
            raise RuntimeError(f"TFLite failed to {step} {self.name} (status {status}).")
