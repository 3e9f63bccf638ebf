"""Hand-written LLVM IR for the block Cholesky's innermost kernels (numba intrinsics).

numba leaves LLVM's SLP vectorizer off, so fixed-size register tiles written in Python stay
scalar; these intrinsics emit the vector code directly: ``<4 x double>`` loads, broadcasts and
``llvm.fma``. The target's vector width is not assumed: LLVM legalizes ``<4 x double>`` on any
x86-64 (two SSE registers without AVX).
"""

from __future__ import annotations

from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

_F64 = ir.DoubleType()
_V4 = ir.VectorType(_F64, 4)
_I64 = ir.IntType(64)
_I32 = ir.IntType(32)


@intrinsic
def prefetch(typingctx, arr, idx):
    """Hint the CPU to fetch ``arr[idx]``'s cache line for writing (``llvm.prefetch``)."""
    sig = types.void(arr, idx)

    def codegen(context, builder, signature, args):
        aryty = signature.args[0]
        ary = context.make_array(aryty)(context, builder, args[0])
        ptr = cgutils.get_item_pointer(context, builder, aryty, ary, [args[1]], wraparound=False)
        i8p = ir.IntType(8).as_pointer()
        i32 = ir.IntType(32)
        fnty = ir.FunctionType(ir.VoidType(), [i8p, i32, i32, i32])
        fn = cgutils.get_or_insert_function(builder.module, fnty, "llvm.prefetch.p0")
        builder.call(fn, [builder.bitcast(ptr, i8p), ir.Constant(i32, 1), ir.Constant(i32, 3),
                          ir.Constant(i32, 1)])
        return context.get_dummy_value()

    return sig, codegen


def _tile_codegen(subtract):
    """Codegen of an 8 x 4 tile of ``B B^T``, stored (``C = tile``) or subtracted (``C -= tile``)."""

    def codegen(context, builder, signature, args):
        Ld = context.make_array(signature.args[0])(context, builder, args[0]).data
        Cd = context.make_array(signature.args[5])(context, builder, args[5]).data
        a_, b_, ld_, w_, c_, ldc_ = args[1], args[2], args[3], args[4], args[6], args[7]
        fma = cgutils.get_or_insert_function(
            builder.module, ir.FunctionType(_V4, [_V4, _V4, _V4]), "llvm.fma.v4f64")
        v4p = _V4.as_pointer()
        zero = ir.Constant(_V4, [0.0] * 4)
        undef = ir.Constant(_V4, ir.Undefined)
        splat = ir.Constant(ir.VectorType(_I32, 4), [0, 0, 0, 0])
        pre = builder.block
        header = builder.append_basic_block("tile.header")
        body = builder.append_basic_block("tile.body")
        done = builder.append_basic_block("tile.done")
        builder.branch(header)
        builder.position_at_end(header)
        k = builder.phi(_I64)
        k.add_incoming(ir.Constant(_I64, 0), pre)
        acc = []
        for _ in range(8):
            p = builder.phi(_V4)
            p.add_incoming(zero, pre)
            acc.append(p)
        builder.cbranch(builder.icmp_unsigned("<", k, w_), body, done)
        builder.position_at_end(body)
        off = builder.mul(k, ld_)
        pa = builder.gep(Ld, [builder.add(a_, off)])
        va0 = builder.load(builder.bitcast(pa, v4p), align=8)
        va1 = builder.load(builder.bitcast(builder.gep(pa, [ir.Constant(_I64, 4)]), v4p),
                           align=8)
        pb = builder.gep(Ld, [builder.add(b_, off)])
        new = []
        for j in range(4):
            s = builder.load(builder.gep(pb, [ir.Constant(_I64, j)]), align=8)
            bj = builder.shuffle_vector(builder.insert_element(undef, s, ir.Constant(_I32, 0)),
                                        undef, splat)
            new.append(builder.call(fma, [va0, bj, acc[2 * j]]))
            new.append(builder.call(fma, [va1, bj, acc[2 * j + 1]]))
        k1 = builder.add(k, ir.Constant(_I64, 1))
        end = builder.block
        builder.branch(header)
        k.add_incoming(k1, end)
        for p, v in zip(acc, new):
            p.add_incoming(v, end)
        builder.position_at_end(done)
        for j in range(4):
            pc = builder.gep(Cd, [builder.add(c_, builder.mul(ir.Constant(_I64, j), ldc_))])
            for h, ptr in enumerate((pc, builder.gep(pc, [ir.Constant(_I64, 4)]))):
                vp = builder.bitcast(ptr, v4p)
                val = acc[2 * j + h]
                if subtract:
                    val = builder.fsub(builder.load(vp, align=8), val)
                builder.store(val, vp, align=8)
        return context.get_dummy_value()

    return codegen


@intrinsic
def syrk_tile(typingctx, L, a, b, ld, w, C, c, ldc):
    """An 8 x 4 tile of ``B B^T``: ``C[c + i + j ldc] = sum_k L[a + i + k ld] L[b + j + k ld]``.

    ``i < 8``, ``j < 4``, ``k < w`` (all integer arguments unsigned 64-bit). Reads 8 rows from
    ``a`` and 4 from ``b`` in each of ``w`` columns; writes the whole tile (callers pad ``C``).
    """
    return types.void(L, a, b, ld, w, C, c, ldc), _tile_codegen(False)


@intrinsic
def syrk_tile_sub(typingctx, L, a, b, ld, w, C, c, ldc):
    """``syrk_tile`` subtracted from ``C`` in place (``C`` may be ``L`` itself: all reads of the
    product happen before the tile is written)."""
    return types.void(L, a, b, ld, w, C, c, ldc), _tile_codegen(True)
