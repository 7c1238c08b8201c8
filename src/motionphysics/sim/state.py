"""Dynamic simulation state (Newton style): what changes every substep.

A :class:`State` holds per-particle arrays only; the solver ping-pongs two of them
(``step(state_in, state_out, dt)``). Grid scratch belongs to the solver, static data
(volumes, materials, grid geometry, boundary program) to the :class:`~.model.Model`.
"""

from __future__ import annotations

import ctypes
from dataclasses import dataclass

import numpy as np

from motionphysics.runtime import init_warp


@dataclass
class State:
    """Particle state at one instant.

    Attributes:
        x: 3D positions of particles [m], shape (particle_count,), dtype vec3.
        v: velocities of particles [m/s], shape (particle_count,), dtype vec3.
        C: APIC affine velocity matrix (approximate velocity gradient) [1/s],
            shape (particle_count,), dtype mat33.
        F: elastic deformation gradient after the last return mapping [-],
            shape (particle_count,), dtype mat33. (A fluid keeps J^(1/3) I.)
        ep: accumulated plastic strain [-] (von Mises / Drucker-Prager / Herschel-Bulkley
            increments; drives plasticine softening), shape (particle_count,), dtype float32.
        active: 1 = simulated, 0 = removed by a ``cut`` collider (P2G multiplies the
            particle's mass, momentum and stress by it; never differentiated),
            shape (particle_count,), dtype float32.
    """

    x: object
    v: object
    C: object
    F: object
    ep: object
    active: object = None

    FIELDS = ("x", "v", "C", "F", "ep")
    """The differentiable fields (``active`` is a mask, copied but never differentiated)."""

    @property
    def particle_count(self) -> int:
        return self.x.shape[0]

    @property
    def requires_grad(self) -> bool:
        return bool(self.x.requires_grad)

    @classmethod
    def zeros(cls, particle_count: int, device: str, requires_grad: bool = False) -> State:
        """A state with all fields zero (F and C too)."""
        wp = init_warp()
        kw = {"device": device, "requires_grad": requires_grad}
        return cls(
            x=wp.zeros(particle_count, dtype=wp.vec3, **kw),
            v=wp.zeros(particle_count, dtype=wp.vec3, **kw),
            C=wp.zeros(particle_count, dtype=wp.mat33, **kw),
            F=wp.zeros(particle_count, dtype=wp.mat33, **kw),
            ep=wp.zeros(particle_count, dtype=float, **kw),
            active=wp.ones(particle_count, dtype=float, device=device),
        )

    @classmethod
    def from_numpy(
        cls,
        x: np.ndarray,
        v: np.ndarray | None = None,
        device: str = "cpu",
        requires_grad: bool = False,
    ) -> State:
        """Rest state at positions ``x`` [m] (P, 3): F = I, C = 0, ep = 0, velocity ``v`` (P, 3)."""
        wp = init_warp()
        x = np.ascontiguousarray(x, dtype=np.float32).reshape(-1, 3)
        p = x.shape[0]
        v = np.zeros_like(x) if v is None else np.broadcast_to(np.asarray(v, np.float32), (p, 3))
        eye = np.broadcast_to(np.eye(3, dtype=np.float32), (p, 3, 3))
        kw = {"device": device, "requires_grad": requires_grad}
        return cls(
            x=wp.array(x, dtype=wp.vec3, **kw),
            v=wp.array(np.ascontiguousarray(v), dtype=wp.vec3, **kw),
            C=wp.zeros(p, dtype=wp.mat33, **kw),
            F=wp.array(np.ascontiguousarray(eye), dtype=wp.mat33, **kw),
            ep=wp.zeros(p, dtype=float, **kw),
            active=wp.ones(p, dtype=float, device=device),
        )

    def clone(self, requires_grad: bool | None = None) -> State:
        """A deep copy (not recorded on a tape); optionally with/without gradient buffers."""
        wp = init_warp()
        rg = self.requires_grad if requires_grad is None else requires_grad
        return State(
            **{f: wp.clone(getattr(self, f), requires_grad=rg) for f in self.FIELDS},
            active=wp.clone(self.active, requires_grad=False),
        )

    def assign(self, other: State) -> None:
        """Copy the values of ``other`` into this state (not recorded on a tape)."""
        for f in self.FIELDS:
            copy_array(getattr(self, f), getattr(other, f))
        copy_array(self.active, other.active)

    def zero_grad(self) -> None:
        for f in self.FIELDS:
            a = getattr(self, f)
            if a.grad is not None:
                a.grad.zero_()

    def numpy(self) -> dict[str, np.ndarray]:
        """Host copies: x, v (P, 3), C, F (P, 3, 3), ep, active (P,), float32."""
        return {f: getattr(self, f).numpy().copy() for f in (*self.FIELDS, "active")}


def copy_array(dst, src) -> None:
    """``wp.copy(dst, src)``, by one ``memmove`` where that is all it would do: same-sized
    contiguous CPU arrays of one element size, not both with gradients (``wp.copy`` then
    also copies, and under a tape records, the gradients). ``wp.copy``'s checks cost ~8 us
    a call, several times the copy of a 1,500-particle field; a recorded substep makes 3."""
    wp = init_warp()
    if (
        (dst.grad is None or src.grad is None)
        and dst.size == src.size
        and dst.device.is_cpu
        and src.device.is_cpu
        and dst.is_contiguous
        and src.is_contiguous
    ):
        size = wp.types.type_size_in_bytes(src.dtype)
        if size == wp.types.type_size_in_bytes(dst.dtype):
            ctypes.memmove(dst.ptr, src.ptr, size * src.size)
            return
    wp.copy(dst, src)
