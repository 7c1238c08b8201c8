"""CPU kernel launches packed once per call site and re-bound, not re-packed.

``wp.launch`` converts every argument to ctypes on every call: ~20-30 us for a kernel of
15-25 arguments, which is most of the cost of the small kernels of a substep (the bounding
box, the boundary hooks, the region copies, the grid update's adjoint) and a tenth of the
large ones at the particle counts people refine (1,500 particles: a recorded substep and
its backward make ~14 launches around ~1 ms of kernel time). A recorded rollout cannot
replay launches by array identity (``solver._Replays``): every recorded substep has its
own states and grid. But from one substep to the next a call site launches the same
kernel over the same dimension with arrays of the same dtype, shape and strides; only the
arrays' pointers and some scalars differ.

:class:`Rebinds` keys a packed launch by the kernel, the dimension, the calling thread
and the *signature* of the arguments (array dtype / shape / strides, None, or the type of
a scalar), and on each call writes into the packed argument struct only what changed: an
array's C descriptor (``array.__ctype__()``, cached by Warp on the array and rebuilt when
its gradient changes, so a new descriptor object means new pointers) and scalars whose
value changed. The kernel, its inputs and outputs are the same as ``wp.launch``'s: bitwise
the same results (tested against ``wp.launch`` for forward and adjoint launches).

The forward and adjoint entry points are called the way Warp's own CPU path calls them
(``hooks.forward(bounds, args)``, ``hooks.backward(bounds, args, adj_args)``). Anything
else falls back to ``wp.launch`` with ``record_tape=False``: a CUDA device, Warp's debug or
floating-point-verification mode, a CPU graph capture, or an argument that is neither a
plain ``wp.array``, None, a number, a tuple nor a Warp vector / matrix value (a struct
could change in place unnoticed). Nothing launched here is recorded on a tape: the callers record
their own adjoints.
"""

from __future__ import annotations

import ctypes
import threading
from typing import Any

import numpy as np

__all__ = ["Rebinds"]

_SCALARS = (int, float, bool, np.integer, np.floating)


def _kind(sig) -> str:
    """How an argument with signature entry ``sig`` (:meth:`Rebinds.launch`) is re-bound:
    "array" (its descriptor), "none", "vector" (a Warp vector / matrix value, by its bytes)
    or "scalar" (a number or a tuple of numbers, by value)."""
    if sig is None:
        return "none"
    if isinstance(sig, tuple):
        return "scalar" if sig[0] is tuple else "array"
    return "vector" if issubclass(sig, ctypes.Array) else "scalar"


class _Packed:
    """One packed launch: the argument structs, their field names, what was written last."""

    __slots__ = ("call", "keep", "names", "adj_names", "args", "adj_args", "last", "kinds")

    def __init__(self, call, keep, names, adj_names, args, adj_args, kinds) -> None:
        self.call = call
        self.keep = keep
        self.names = names
        self.adj_names = adj_names
        self.args = args
        self.adj_args = adj_args
        self.kinds = kinds
        self.last: list[Any] = [None] * len(kinds)


class Rebinds:
    """Packed CPU launches re-bound to new arrays (see the module docstring)."""

    MAX = 512
    """Packed launches kept (least recently packed dropped first)."""

    def __init__(self, wp, device, enabled: bool = True) -> None:
        from warp._src import context as ctx

        self.wp = wp
        self.device = device
        self._ctx = ctx
        self._array = wp.array
        self._entries: dict = {}
        self._lock = threading.Lock()
        cfg = wp.config
        self.enabled = enabled and device.is_cpu and cfg.mode != "debug" and not cfg.verify_fp
        self.packs = 0
        """How many launches were packed (a test and a profile read it)."""

    def launch(
        self,
        kernel,
        dim,
        inputs: list,
        outputs: list,
        adj_inputs: list | None = None,
        adj_outputs: list | None = None,
        adjoint: bool = False,
    ) -> None:
        """``wp.launch(kernel, dim, inputs, outputs[, adj_inputs, adj_outputs], adjoint,
        record_tape=False)`` on this launcher's device."""
        vals = [*inputs, *outputs]
        if adjoint:
            vals += [*(adj_inputs or []), *(adj_outputs or [])]
        if not self.enabled or self._ctx._get_apic_capture_for_device(self.device) is not None:
            self._fallback(kernel, dim, inputs, outputs, adj_inputs, adj_outputs, adjoint)
            return
        array = self._array
        sig: list[Any] = [kernel, dim if isinstance(dim, int) else tuple(dim), adjoint]
        sig.append(threading.get_ident())  # two chunks' threads never share a packed struct
        for a in vals:
            t = type(a)
            if t is array:
                sig.append((a.dtype, a.shape, a.strides))
            elif a is None:
                sig.append(None)
            elif isinstance(a, ctypes.Array):  # a Warp vector / matrix value
                sig.append(t)
            elif isinstance(a, _SCALARS):
                sig.append(t)
            elif t is tuple:  # a vector given as a tuple of numbers
                sig.append((tuple, len(a)))
            else:
                self._fallback(kernel, dim, inputs, outputs, adj_inputs, adj_outputs, adjoint)
                return
        key = tuple(sig)
        entry = self._entries.get(key)
        if entry is None:
            entry = self._pack(
                key, kernel, dim, inputs, outputs, adj_inputs, adj_outputs, adjoint, vals
            )
            if entry is None:
                return  # packed and launched by the fallback
        else:
            self._rebind(entry, kernel, vals)
        entry.call()

    def _warp(self, kernel, dim, inputs, outputs, adj_inputs, adj_outputs, adjoint, **kw):
        """``wp.launch`` of these arguments on this device, never recorded on a tape."""
        if adjoint:
            kw.update(adj_inputs=adj_inputs or [], adj_outputs=adj_outputs or [])
        return self.wp.launch(
            kernel,
            dim=dim,
            inputs=inputs,
            outputs=outputs,
            device=self.device,
            adjoint=adjoint,
            record_tape=False,
            **kw,
        )

    def _fallback(self, kernel, dim, inputs, outputs, adj_inputs, adj_outputs, adjoint) -> None:
        self._warp(kernel, dim, inputs, outputs, adj_inputs, adj_outputs, adjoint)

    def _rebind(self, entry: _Packed, kernel, vals: list) -> None:
        n = len(entry.names)
        last, kinds = entry.last, entry.kinds
        for i, a in enumerate(vals):
            kind = kinds[i]
            if kind == "array":
                c = a.__ctype__()
                if c is last[i]:
                    continue
                last[i] = c
            elif kind == "none":
                continue
            else:  # a scalar or a Warp vector / matrix value: re-packed when it changed
                v = bytes(a) if kind == "vector" else a
                if v == last[i]:
                    continue
                last[i] = v
                arg = kernel.adj.args[i if i < n else i - n]
                c = self._ctx.pack_arg(kernel, arg.type, arg.label, a, self.device, i >= n)
            if i < n:
                setattr(entry.args, entry.names[i], c)
            else:
                setattr(entry.adj_args, entry.adj_names[i - n], c)

    def _pack(self, key, kernel, dim, inputs, outputs, adj_inputs, adj_outputs, adjoint, vals):
        """Pack the launch (Warp's own argument checks and conversions), keep it under
        ``key`` and return it (the caller runs it); None when Warp did not give a CPU
        launch to keep (then it has been launched here). ``vals``: the inputs, outputs and
        adjoints in order, whose signature ends ``key`` (how each is re-bound follows from
        it: no second classification)."""
        cmd = self._warp(
            kernel, dim, inputs, outputs, adj_inputs, adj_outputs, adjoint, record_cmd=True
        )
        if not isinstance(cmd, self._ctx.Launch):
            self._fallback(kernel, dim, inputs, outputs, adj_inputs, adj_outputs, adjoint)
            return None
        args, adj_args = self._ctx._build_cpu_args_structs(kernel, cmd.hooks, cmd.params, adjoint)
        names = [f[0] for f in args._fields_]
        adj_names = [f[0] for f in adj_args._fields_] if adjoint else []
        b, x = ctypes.byref(cmd.bounds), ctypes.byref(args)
        if adjoint:
            hook, y = cmd.hooks.backward, ctypes.byref(adj_args)

            def call() -> None:
                hook(b, x, y)

        else:
            hook = cmd.hooks.forward

            def call() -> None:
                hook(b, x)

        kinds = [_kind(k) for k in key[len(key) - len(vals) :]]
        keep = (cmd.bounds, cmd.module_exec)  # alive as long as the entry
        entry = _Packed(call, keep, names, adj_names, args, adj_args, kinds)
        for i, (a, k) in enumerate(zip(vals, kinds, strict=True)):
            # what was packed: an array's cached descriptor (the same object pack_arg used)
            entry.last[i] = a.__ctype__() if k == "array" else bytes(a) if k == "vector" else a
        with self._lock:
            if len(self._entries) >= self.MAX:
                del self._entries[next(iter(self._entries))]
            self._entries[key] = entry
            self.packs += 1
        return entry
