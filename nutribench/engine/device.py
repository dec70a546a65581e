"""Where the batched engine trains: ``--device auto|cpu|cuda`` (or ``cuda:N``).

``auto`` is CUDA when this torch sees a GPU, else the CPU; ``cuda`` where there is none is
refused in one line. The engine keeps every random stream on the CPU (numpy generators and
CPU ``torch.Generator`` s: the draws are the same on every device) and moves what they give
to the device; its agents are handed back with CPU weights, so saved models load anywhere.

Checking a name (:func:`check_device`) never starts CUDA for ``auto`` or ``cpu``, and for
``cuda`` only asks how many devices there are, so the driver of ``nutribench run`` can check
``--device`` before it starts its workers; for ``auto`` or ``cpu`` it does not even import
torch, so that a run or a study says what it starts before torch loads.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from nutribench.errors import UserError

if TYPE_CHECKING:
    import torch as th

#: the ``--device`` values (besides ``cuda:N``, a CUDA device by its index)
DEVICES = ("auto", "cpu", "cuda")


class DeviceError(UserError):
    """An unknown ``--device``, or CUDA asked for where there is none (one line for users)."""


def _parse(name: str | th.device) -> tuple[str, int | None]:
    """``("auto" | "cpu" | "cuda", index or None)``, or a DeviceError for an unknown name."""
    text = str(name).strip().lower()
    kind, _, index = text.partition(":")
    if kind in DEVICES and not index:
        return kind, None
    if kind == "cuda" and index.isdigit():
        return kind, int(index)
    raise DeviceError(f"--device {str(name)!r}: use auto, cpu, cuda or cuda:N")


def _check_cuda(name: str | th.device, index: int | None) -> None:
    """Refuse CUDA where this torch has none, or a device index beyond the count, in one line."""
    import torch as th

    if not th.cuda.is_available():
        why = "this torch is built without CUDA" if th.version.cuda is None else "no CUDA device is visible"
        raise DeviceError(f"--device {name}: CUDA is not available here ({why}); use --device cpu or --device auto")
    count = th.cuda.device_count()
    if index is not None and index >= count:
        raise DeviceError(
            f"--device {name}: this machine has {count} CUDA device(s), cuda:0 to cuda:{count - 1}; "
            "use one of them, or --device auto"
        )


def check_device(name: str | th.device) -> None:
    """Refuse an unknown ``name``, or CUDA where there is none (DeviceError, one line),
    without starting CUDA (``auto`` is not checked further: it never fails)."""
    kind, index = _parse(name)
    if kind == "cuda":
        _check_cuda(name, index)


def resolve_device(name: str | th.device) -> th.device:
    """The torch device of ``name``: ``auto`` -> ``cuda`` if ``torch.cuda.is_available()``
    else ``cpu``; ``cuda`` -> the current CUDA device, with its index (so that it compares
    equal to a tensor's ``.device``); ``cuda:N`` -> that one. Raises DeviceError (one line)
    for an unknown name, or CUDA where there is none."""
    import torch as th

    kind, index = _parse(name)
    if kind == "cuda":
        _check_cuda(name, index)
    if kind == "cpu" or (kind == "auto" and not th.cuda.is_available()):
        return th.device("cpu")
    return th.device("cuda", th.cuda.current_device() if index is None else index)


def leaves_on(params: list[th.Tensor], device: th.device | str | None) -> list[th.Tensor]:
    """``params`` (made on the CPU, from the CPU's random streams) as leaf tensors on
    ``device``, each requiring grad as before: the very same tensors where they are there
    already (None, or the CPU: nothing changes), copies elsewhere. Move parameters before an
    optimiser is made over them."""
    if device is None:
        return params
    import torch as th

    device = th.device(device)
    return [p if p.device == device else p.detach().to(device).requires_grad_(p.requires_grad) for p in params]
