"""Count what a training step or a sampling call would launch on a GPU, measured on any device.

On a GPU every aten op that computes is a kernel launch (5-10 us of CPU time whatever its size) and every
host sync (`.item()`, a data-dependent shape) drains the launch queue, so small point-cloud networks are
bound by these counts, not by FLOPs. `LaunchCounter` is a `TorchDispatchMode` that sees every aten op the
code dispatches; ops that only make a view or reserve memory are not counted. Run the code under
`device_code_paths()` (in `lerobot_taxdpd.maths.geometry`) so that CPU-only shortcuts take their device
branch and the count on the CPU is what a GPU would launch.
"""

from __future__ import annotations

import contextlib
from collections import Counter
from collections.abc import Iterator

import torch
from torch import nn
from torch.utils._python_dispatch import TorchDispatchMode

aten = torch.ops.aten

#: Ops that launch nothing: they allocate, or describe existing memory another way.
NON_LAUNCHING = {
    aten.empty.memory_format,
    aten.empty_strided.default,
    aten.empty_like.default,
    aten._unsafe_view.default,
    aten.lift_fresh.default,
    aten.set_.source_Storage_storage_offset,
    aten.resize_.default,
}
#: Ops that make the host wait for the device: a value read back, or an output whose shape depends on data.
SYNCING = {
    aten._local_scalar_dense.default,
    aten.nonzero.default,
    aten.masked_select.default,
    aten.is_nonzero.default,
    aten.equal.default,
    aten.unique_consecutive.default,
    aten._unique2.default,
    aten.unique_dim.default,
    aten.repeat_interleave.Tensor,
}

#: Tensor methods that copy values to the host without an aten op on the CPU.
HOST_READS = ("tolist", "numpy")


def _is_boolean_index(func, args) -> bool:
    """`x[mask]` (aten.index with a bool tensor): its output size is the mask's count, read back from the device."""
    if func not in (aten.index.Tensor, aten.index_put_.default, aten.index_put.default):
        return False
    return any(isinstance(i, torch.Tensor) and i.dtype == torch.bool for i in args[1] if i is not None)


class LaunchCounter(TorchDispatchMode):
    """Kernel-launching ops and host syncs, by stage (`with counter.stage("backward"): ...`).

    `ops[stage]` counts launches by op name, `syncs[stage]` host syncs by op name. `label_modules` makes the
    forward pass of chosen modules count under their own stage (the innermost labelled module wins).
    """

    def __init__(self) -> None:
        super().__init__()
        self._stages = ["other"]
        self.ops: dict[str, Counter] = {}
        self.syncs: dict[str, Counter] = {}

    @contextlib.contextmanager
    def stage(self, name: str) -> Iterator[None]:
        self._stages.append(name)
        try:
            yield
        finally:
            self._stages.pop()

    def label_modules(self, stages: dict[str, nn.Module | list[nn.Module]], stack: contextlib.ExitStack) -> None:
        """Count each module's forward under its stage name, until `stack` closes."""

        def leave(*_) -> None:  # a forward hook that returns something replaces the module's output
            self._stages.pop()

        for name, modules in stages.items():
            for module in modules if isinstance(modules, list) else [modules]:
                stack.callback(module.register_forward_pre_hook(lambda *_, n=name: self._stages.append(n)).remove)
                stack.callback(module.register_forward_hook(leave).remove)

    def __enter__(self):
        # Reading a tensor into Python or numpy is not an aten op on the CPU, but on a GPU it waits for the device.
        self._unpatched = {name: getattr(torch.Tensor, name) for name in HOST_READS}
        for name, method in self._unpatched.items():
            setattr(torch.Tensor, name, self._counted_read(name, method))
        return super().__enter__()

    def __exit__(self, *exc):
        for name, method in self._unpatched.items():
            setattr(torch.Tensor, name, method)
        return super().__exit__(*exc)

    def _counted_read(self, name: str, method):
        def read(tensor, *args, **kwargs):
            self.syncs.setdefault(self._stages[-1], Counter())[name] += 1
            return method(tensor, *args, **kwargs)

        return read

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        stage = self._stages[-1]
        if func in SYNCING or _is_boolean_index(func, args):
            self.syncs.setdefault(stage, Counter())[str(func.overloadpacket.__name__)] += 1
        if func not in NON_LAUNCHING and not func.is_view and func not in SYNCING:
            self.ops.setdefault(stage, Counter())[str(func.overloadpacket.__name__)] += 1
        return func(*args, **(kwargs or {}))

    # ------------------------------------------------------------------------------------------ report
    def total_ops(self) -> int:
        return sum(sum(c.values()) for c in self.ops.values())

    def total_syncs(self) -> int:
        return sum(sum(c.values()) for c in self.syncs.values())

    def summary(self, top: int = 8) -> dict:
        """Totals, per-stage counts and the most frequent ops: JSON-ready."""
        return {
            "ops": self.total_ops(),
            "syncs": self.total_syncs(),
            "ops_by_stage": {stage: sum(c.values()) for stage, c in self.ops.items()},
            "syncs_by_stage": {stage: dict(c) for stage, c in self.syncs.items()},
            "top_ops": dict(sum(self.ops.values(), Counter()).most_common(top)),
        }
