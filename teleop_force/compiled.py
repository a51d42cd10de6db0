"""Compilation of the model's numerical terms with numba (nopython), cached on disk.

Every model term (friction, wavelets, coverage trust, found effects) is one
:func:`njit_cached` function on plain floats and arrays, so the batch fits, the streaming
estimator and other compiled code call the same definition. :func:`view_2d` and
:func:`view_3d` cut shaped views out of flat scratch and table buffers in compiled code at no
cost (numba's ``reshape`` costs ~70 ns a call, too much for the 1 kHz step).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numba
from numba import types
from numba.core import cgutils
from numba.core.imputils import impl_ret_borrowed
from numba.extending import intrinsic
from numba.np.arrayobj import make_array, populate_array


def njit_cached(**options: Any) -> Callable[[Callable[..., Any]], Any]:
    """``numba.njit(cache=True, nogil=True, **options)``; in memory where no cache can be written.

    The compiled code is cached next to the module, or where numba's cache locator finds a
    writable place; when there is none it is compiled on first use in every process.
    """
    options = {"nogil": True, **options}

    def wrap(fn: Callable[..., Any]) -> Any:
        try:
            return numba.njit(cache=True, **options)(fn)
        except RuntimeError:  # numba found no writable cache location
            return numba.njit(cache=False, **options)(fn)

    return wrap


def _view_codegen(ndim: int) -> Callable[..., Any]:
    """Code of a C-contiguous ``ndim`` view at an offset of a 1-D C-contiguous array."""

    def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
        source_type = signature.args[0]
        source = make_array(source_type)(context, builder, args[0])
        view = make_array(signature.return_type)(context, builder)
        itemsize = context.get_constant(
            types.intp, context.get_abi_sizeof(context.get_data_type(source_type.dtype))
        )
        shape = list(args[2 : 2 + ndim])
        strides = [itemsize]
        for extent in reversed(shape[1:]):
            strides.insert(0, builder.mul(extent, strides[0]))
        populate_array(
            view,
            data=cgutils.gep_inbounds(builder, source.data, args[1]),
            shape=cgutils.pack_array(builder, shape),
            strides=cgutils.pack_array(builder, strides),
            itemsize=itemsize,
            meminfo=source.meminfo,
            parent=source.parent,
        )
        return impl_ret_borrowed(context, builder, signature.return_type, view._getvalue())

    return codegen


def _view_signature(buffer: Any, ndim: int) -> Any:
    if not (isinstance(buffer, types.Array) and buffer.ndim == 1 and buffer.layout == "C"):
        return None
    return types.Array(buffer.dtype, ndim, "C")(buffer, *([types.intp] * (1 + ndim)))


def _view_2d(typingctx: Any, buffer: Any, offset: Any, rows: Any, cols: Any) -> Any:
    signature = _view_signature(buffer, 2)
    return None if signature is None else (signature, _view_codegen(2))


def _view_3d(typingctx: Any, buffer: Any, offset: Any, d0: Any, d1: Any, d2: Any) -> Any:
    signature = _view_signature(buffer, 3)
    return None if signature is None else (signature, _view_codegen(3))


#: ``view_2d(buffer, offset, rows, cols)``: ``buffer[offset : offset + rows * cols].reshape(
#: rows, cols)`` without numba's reshape, in compiled code only. numba's ``reshape`` calls a C
#: helper (~70 ns); this builds the view in place (~1 ns). The caller guarantees the view lies
#: inside ``buffer`` (no check).
view_2d: Any = intrinsic(_view_2d)
#: ``view_3d(buffer, offset, d0, d1, d2)``: :data:`view_2d` in three dimensions.
view_3d: Any = intrinsic(_view_3d)
