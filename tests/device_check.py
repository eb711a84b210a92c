"""A device other than the CPU, on a machine without a GPU: tensors that report the meta device but hold their
values on the CPU, so that a training step really runs (losses, masks, `.item()`, boolean indexing) while every
tensor made on the CPU in the middle of it is caught where it meets the device's tensors, as CUDA would refuse it
("Expected all tensors to be on the same device").

Why not the fake CUDA tensors torch.compile traces with (torch._subclasses.fake_tensor.FakeTensorMode): on a CPU
build of torch their backward aborts the process ("PyTorch is not linked with support for cuda devices"), and they
hold no values, so a step that reads a mask's count or indexes with a boolean mask cannot run. Nor the bare meta
device: no values either.

    with on_device():                          # inside: .to(DEVICE) gives OnDevice tensors
        module.to(DEVICE)
        batch = move_data_to_device(batch, DEVICE)
        ...                                    # CpuTensorOnDevice if a CPU-made tensor meets the device's

The rules follow CUDA's: a 0-dim CPU tensor may meet device tensors (a CPU scalar), index tensors may be on the CPU
(`x[cpu_index]`), `copy_` copies across devices; anything else raises.
"""

from __future__ import annotations

from contextlib import contextmanager

import torch
from torch.overrides import TorchFunctionMode
from torch.utils._python_dispatch import TorchDispatchMode
from torch.utils._pytree import tree_map

DEVICE = torch.device("meta")


class CpuTensorOnDevice(RuntimeError):
    """A tensor made on the CPU met tensors on the device."""


class OnDevice(torch.Tensor):
    """A tensor that says it is on DEVICE; its values are a CPU tensor (`_cpu`)."""

    @staticmethod
    def __new__(cls, data: torch.Tensor):
        r = torch.Tensor._make_wrapper_subclass(cls, data.shape, strides=data.stride(),
                                                storage_offset=data.storage_offset(), dtype=data.dtype,
                                                device=DEVICE, requires_grad=data.requires_grad)
        r._cpu = data
        return r

    def __repr__(self) -> str:
        return f"OnDevice({self._cpu!r})"

    @classmethod
    def __torch_dispatch__(cls, func, types, args=(), kwargs=None):
        return _run(func, args, kwargs or {})


# Ops whose index arguments may be CPU tensors (CUDA moves them), and the copy across devices.
_INDEX_OPS = {"aten.index.Tensor": (1,), "aten.index_put_.default": (1,), "aten.index_put.default": (1,),
              "aten._index_put_impl_.default": (1,)}
_CROSS_DEVICE = {"aten.copy_.default", "aten._to_copy.default", "aten.set_.source_Tensor"}


def _tensors(tree) -> list[torch.Tensor]:
    found: list[torch.Tensor] = []
    tree_map(lambda x: found.append(x) if isinstance(x, torch.Tensor) else None, tree)
    return found


def _run(func, args, kwargs):
    name = str(func)
    checked = [a for i, a in enumerate(args) if i not in _INDEX_OPS.get(name, ())]
    wrapped = [x for x in _tensors((args, kwargs)) if isinstance(x, OnDevice)]
    if wrapped and name not in _CROSS_DEVICE:
        for x in _tensors((checked, kwargs)):
            if isinstance(x, OnDevice) or x.dim() == 0 and x.device.type == "cpu":
                continue
            where = "made on the CPU" if x.device.type == "cpu" else f"on {x.device} without values"
            raise CpuTensorOnDevice(f"{name}: a tensor of shape {tuple(x.shape)} {where} meets tensors on the device "
                                    f"(on a GPU: 'Expected all tensors to be on the same device')")
    device = kwargs.get("device")
    to_device = device is not None and torch.device(device).type == DEVICE.type
    to_cpu = device is not None and not to_device
    args, kwargs = tree_map(lambda x: x._cpu if isinstance(x, OnDevice) else x, (args, kwargs))
    if device is not None:
        kwargs["device"] = torch.device("cpu")
    out = func(*args, **kwargs)
    same = {id(x._cpu): x for x in wrapped}  # in-place ops return their input
    wrap = bool(wrapped and not to_cpu) or to_device

    def rewrap(x):
        if isinstance(x, torch.Tensor) and not isinstance(x, OnDevice):
            if id(x) in same:
                return same[id(x)]
            return OnDevice(x) if wrap else x
        return x

    return tree_map(rewrap, out)


class _Dispatch(TorchDispatchMode):
    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        return _run(func, args, kwargs or {})


class _FromData(TorchFunctionMode):
    """torch.tensor(data, device=DEVICE) and x.new_tensor(data): made on the CPU and wrapped (a meta tensor made the
    usual way would have no values)."""

    def __torch_function__(self, func, types, args=(), kwargs=None):
        kwargs = kwargs or {}
        if func in (torch.tensor, torch.as_tensor, torch.asarray) and kwargs.get("device") is not None \
                and torch.device(kwargs["device"]).type == DEVICE.type:
            return OnDevice(func(*args, **{**kwargs, "device": "cpu"}))
        if func is torch.Tensor.new_tensor and isinstance(args[0], OnDevice) and kwargs.get("device") is None:
            return OnDevice(args[0]._cpu.new_tensor(*args[1:], **kwargs))
        return func(*args, **kwargs)


@contextmanager
def on_device():
    """Inside: DEVICE is a device with values (see the module docstring)."""
    with _FromData(), _Dispatch():
        yield
