"""Records passed to compiled code by reference: a numba structure holding named fields (arrays,
tuples of arrays, numbers), one pointer wide as an argument.

Numba passes a tuple of arrays by value, seven or more machine words per array: the step loop's
~90 arrays were ~700 words pushed per call, a third of a streamed step. A :func:`record` class
instead passes one pointer, and :func:`fields` reads the fields back without numba's reference
counting, for kernels compiled with ``_nrt=False`` (which cannot use structref's own attribute
access): no atomic operation or runtime call per array.
"""
from __future__ import annotations

from numba.core import cgutils, types
from numba.core.runtime.nrtdynmod import _meminfo_struct_type
from numba.experimental import structref
from numba.extending import intrinsic


def record(name: str, field_names: list, doc: str):
    """A new record class: ``cls(*values)`` builds one, from Python or compiled code; its fields
    keep their values alive (they are read with :func:`fields`).

    The class and its numba type are bound in this module under ``name`` and ``name + "Type"``:
    numba's on-disk cache pickles a kernel's signature and finds a type again by its module and
    name; a class found nowhere is pickled by value, comes back as another class, and a kernel
    taking it was compiled again in every process (a minute for a :class:`pwl.streaming.Stream`)."""
    if name in globals():
        raise ValueError(f"pwl.byref: a record named {name!r} exists")
    typ = type(name + "Type", (types.StructRef,), {
        "preprocess_fields": lambda self, f: tuple((n, types.unliteral(t)) for n, t in f), "__module__": __name__})
    structref.register(typ)
    cls = type(name, (structref.StructRefProxy,), {"__doc__": doc, "__module__": __name__})
    structref.define_proxy(cls, typ, list(field_names))
    globals().update({name: cls, typ.__name__: typ})
    return cls


@intrinsic
def fields(typingctx, rec):
    """The fields of the record ``rec`` as a tuple, in their declared order, borrowed (no
    reference counting). The loads are NRT_MemInfo_data_fast's: the payload pointer is the
    meminfo's fourth word."""
    names = [n for n, _ in rec._fields]
    tup = types.Tuple([t for _, t in rec._fields])

    def codegen(context, builder, sig, args):
        ref = cgutils.create_struct_proxy(rec)(context, builder, value=args[0])
        mi = builder.bitcast(ref.meminfo, _meminfo_struct_type.as_pointer())
        data = builder.load(cgutils.gep(builder, mi, 0, 3, inbounds=True))
        payload_type = rec.get_data_type()
        data = builder.bitcast(data, context.data_model_manager[payload_type].get_value_type().as_pointer())
        payload = cgutils.create_struct_proxy(payload_type)(context, builder, ref=data)
        return context.make_tuple(builder, tup, [getattr(payload, n) for n in names])
    return tup(rec), codegen
