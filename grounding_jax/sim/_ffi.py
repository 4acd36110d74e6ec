"""Python functions as XLA FFI handlers on the CPU, through ``ctypes`` (nothing to compile).

Why not ``jax.pure_callback``: a program with a host callback is never written to JAX's
persistent compilation cache (the callback is an object of this process), so every program
that steps C MuJoCo was compiled again in every process. A custom call to a *named* FFI
target is an ordinary, cacheable program; the name is looked up in this process's registry
when the program runs. The handler speaks XLA's FFI C API (``xla/ffi/api/c_api.h``, the
structs below mirror it): it answers the metadata query XLA sends when the target is
registered, and on each call hands the Python function NumPy views of its buffers.
"""

from __future__ import annotations

import ctypes as C
import threading
from collections.abc import Callable

import numpy as np

#: FFI API version the handlers declare: every field read here exists since 0.1.
API_VERSION = (0, 1)
_EXECUTE = 3  # XLA_FFI_ExecutionStage_EXECUTE
_METADATA = 1  # XLA_FFI_Extension_Metadata
_SCALAR = 3  # XLA_FFI_AttrType_SCALAR
_INTERNAL = 13  # XLA_FFI_Error_Code_INTERNAL
_DTYPES = {1: np.bool_, 4: np.int32, 5: np.int64, 11: np.float32, 12: np.float64}

Handler = Callable[[list[np.ndarray], list[np.ndarray], dict[str, object]], None]


class _ExtBase(C.Structure):
    pass


_ExtBase._fields_ = [("struct_size", C.c_size_t), ("type", C.c_int),
                     ("next", C.POINTER(_ExtBase))]


class _Buffer(C.Structure):
    _fields_ = [("struct_size", C.c_size_t), ("ext", C.c_void_p), ("dtype", C.c_int),
                ("data", C.c_void_p), ("rank", C.c_int64), ("dims", C.POINTER(C.c_int64))]


class _List(C.Structure):  # XLA_FFI_Args and XLA_FFI_Rets share this layout
    _fields_ = [("struct_size", C.c_size_t), ("ext", C.c_void_p), ("size", C.c_int64),
                ("types", C.POINTER(C.c_int)), ("items", C.POINTER(C.c_void_p))]


class _ByteSpan(C.Structure):
    _fields_ = [("ptr", C.c_void_p), ("len", C.c_size_t)]


class _Scalar(C.Structure):
    _fields_ = [("dtype", C.c_int), ("value", C.c_void_p)]


class _Attrs(C.Structure):
    _fields_ = [("struct_size", C.c_size_t), ("ext", C.c_void_p), ("size", C.c_int64),
                ("types", C.POINTER(C.c_int)), ("names", C.POINTER(C.POINTER(_ByteSpan))),
                ("items", C.POINTER(C.c_void_p))]


class _CallFrame(C.Structure):
    _fields_ = [("struct_size", C.c_size_t), ("ext", C.POINTER(_ExtBase)),
                ("api", C.c_void_p), ("ctx", C.c_void_p), ("stage", C.c_int),
                ("args", _List), ("rets", _List), ("attrs", _Attrs)]


class _ApiVersion(C.Structure):
    _fields_ = [("struct_size", C.c_size_t), ("ext", C.c_void_p), ("major", C.c_int),
                ("minor", C.c_int)]


class _Metadata(C.Structure):
    _fields_ = [("struct_size", C.c_size_t), ("api_version", _ApiVersion),
                ("traits", C.c_uint32)]


class _MetadataExtension(C.Structure):
    _fields_ = [("base", _ExtBase), ("metadata", C.POINTER(_Metadata))]


class _ErrorCreateArgs(C.Structure):
    _fields_ = [("struct_size", C.c_size_t), ("ext", C.c_void_p), ("message", C.c_char_p),
                ("errc", C.c_int)]


_ErrorCreate = C.CFUNCTYPE(C.c_void_p, C.POINTER(_ErrorCreateArgs))


class _Api(C.Structure):  # only the fields up to XLA_FFI_Error_Create
    _fields_ = [("struct_size", C.c_size_t), ("ext", C.c_void_p),
                ("api_version", _ApiVersion), ("internal_api", C.c_void_p),
                ("error_create", _ErrorCreate)]


def _struct_size(struct: type[C.Structure], last: str) -> int:
    """XLA_FFI_STRUCT_SIZE: the offset of the last field plus its size (no tail padding)."""
    field = getattr(struct, last)
    return field.offset + field.size


_HandlerType = C.CFUNCTYPE(C.c_void_p, C.POINTER(_CallFrame))
_registered: dict[str, object] = {}  # name -> the ctypes function (kept alive here)
_lock = threading.Lock()


def _view(ptr: int) -> np.ndarray:
    buf = C.cast(ptr, C.POINTER(_Buffer)).contents
    if buf.dtype not in _DTYPES:
        raise TypeError(f"FFI buffer dtype code {buf.dtype} is not one of {sorted(_DTYPES)}")
    shape = tuple(buf.dims[i] for i in range(buf.rank))
    dtype = np.dtype(_DTYPES[buf.dtype])
    size = int(np.prod(shape, dtype=np.int64))
    if size == 0:
        return np.zeros(shape, dtype)
    raw = (C.c_char * (size * dtype.itemsize)).from_address(buf.data)
    return np.frombuffer(raw, dtype).reshape(shape)


def _attrs(attrs: _Attrs) -> dict[str, object]:
    out: dict[str, object] = {}
    for i in range(attrs.size):
        span = attrs.names[i].contents
        name = C.string_at(span.ptr, span.len).decode()
        if attrs.types[i] != _SCALAR:
            raise TypeError(f"FFI attribute {name!r}: only scalar attributes are supported")
        scalar = C.cast(attrs.items[i], C.POINTER(_Scalar)).contents
        if scalar.dtype not in _DTYPES:
            raise TypeError(f"FFI attribute {name!r}: dtype code {scalar.dtype} unsupported")
        ctype = np.ctypeslib.as_ctypes_type(np.dtype(_DTYPES[scalar.dtype]))
        out[name] = C.cast(scalar.value, C.POINTER(ctype)).contents.value
    return out


def _error(frame: _CallFrame, message: str) -> int | None:
    api = C.cast(frame.api, C.POINTER(_Api)).contents
    args = _ErrorCreateArgs(_struct_size(_ErrorCreateArgs, "errc"), None,
                            message.encode(errors="replace"), _INTERNAL)
    return api.error_create(C.byref(args))


def _wrap(fn: Handler) -> Callable[[C.POINTER(_CallFrame)], int | None]:
    def handler(frame_ptr):
        frame = frame_ptr.contents
        if frame.ext and frame.ext.contents.type == _METADATA:
            meta = C.cast(frame.ext, C.POINTER(_MetadataExtension)).contents.metadata.contents
            meta.api_version.struct_size = _struct_size(_ApiVersion, "minor")
            meta.api_version.major, meta.api_version.minor = API_VERSION
            meta.traits = 0
            return None
        if frame.stage != _EXECUTE:
            return None
        try:
            ins = [_view(frame.args.items[i]) for i in range(frame.args.size)]
            outs = [_view(frame.rets.items[i]) for i in range(frame.rets.size)]
            fn(ins, outs, _attrs(frame.attrs))
        except BaseException as e:  # noqa: BLE001 -- becomes the XLA error JAX raises
            return _error(frame, f"{type(e).__name__}: {e}")
        return None

    return handler


def register(name: str, fn: Handler | None = None, capsule: object = None) -> None:
    """Register ``fn`` as the CPU FFI target ``name`` (once per process; later calls with
    the same name are no-ops).

    Args:
        name: the target's name, as passed to ``jax.ffi.ffi_call``.
        fn: ``fn(inputs, outputs, attributes)``: NumPy views of the input buffers (read
            them, do not keep them), of the output buffers (fill them in place) and the
            call's scalar attributes by name.
        capsule: instead of ``fn``, a compiled handler already wrapped by
            ``jax.ffi.pycapsule`` (kept alive here).
    """
    import jax

    with _lock:
        if name in _registered:
            return
        if capsule is None:
            cfn = _HandlerType(_wrap(fn))
            capsule, keep = jax.ffi.pycapsule(cfn), cfn
        else:
            keep = capsule
        jax.ffi.register_ffi_target(name, capsule, platform="cpu")
        _registered[name] = keep
