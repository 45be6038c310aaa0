"""The contract between an algorithm service and the transport.

A service is a subclass of :class:`ServiceNode`: it names its input keys (in priority
order for equal stamps) and output keys -- once, in :meth:`ServiceNode.io_keys`, computed
from the configuration and used both by the node instance and by the launcher's wiring
(the class attributes ``inputs``/``outputs`` are the default of ``io_keys``) -- receives its inputs already merged in event-time
order through :meth:`ServiceNode.process`, and emits outputs with :meth:`ServiceNode.publish`.
It never touches Zenoh: :mod:`common.runtime` feeds it from the bus, and :func:`run_offline`
feeds it from a list (unit tests, notebooks, ``poseidon deadreckon`` and the like), giving
exactly the same outputs.
"""
from __future__ import annotations

import logging
from collections.abc import Iterable
from typing import Any, ClassVar, Generic, TypeVar

from pydantic import BaseModel

from common.messages import Header, Message
from common.ordering import EventTimeMerger

__all__ = ["ServiceNode", "run_offline"]

#: a service's own configuration section (``services/<name>/config.py``)
ConfigT = TypeVar("ConfigT", bound=BaseModel)

log = logging.getLogger(__name__)


class ServiceNode(Generic[ConfigT]):
    """Base of every service.  Subclasses set ``name``, ``inputs`` and ``outputs``.

    A node is built from its own configuration section; what it needs from another
    service's section comes as explicit constructor arguments (the launcher's factory,
    ``system/services.py::build_node``, passes them).
    """

    name: ClassVar[str] = ""
    inputs: tuple[str, ...] = ()    # class default of io_keys; the instance's own after __init__
    outputs: tuple[str, ...] = ()

    @classmethod
    def io_keys(cls, config: ConfigT) -> tuple[tuple[str, ...], tuple[str, ...]]:
        """Input keys (priority order) and output keys of this service under its section ``config``.

        The one declaration of a service's wiring: the launcher plans the run with it and
        the instance takes ``self.inputs``/``self.outputs`` from it.  Default: the class
        attributes; override when the keys depend on the configuration.
        """
        return tuple(cls.inputs), tuple(cls.outputs)

    def __init__(self, config: ConfigT):
        self.config = config
        self.inputs, self.outputs = type(self).io_keys(config)
        self._outbox: list[tuple[str, Message]] = []
        self._seq: dict[str, int] = {k: 0 for k in self.outputs}
        self.counters: dict[str, int] = {}

    # ---- called by the runtime -------------------------------------------------
    def process(self, key: str, msg: Message) -> None:
        """Handle one input message (event-time order guaranteed)."""
        raise NotImplementedError(f"{type(self).__name__} must implement process()")

    def finish(self) -> None:
        """Every input ended: flush what is pending (default: nothing)."""

    def warm_up(self) -> None:
        """Do, before the service says it is alive, what would otherwise stall its first inputs
        (compiling numba kernels: tens of seconds on a cold cache, long enough for a live
        service's bounded queue to drop); must leave the node's state as it was.  Default: nothing."""

    def output_watermark(self, input_watermark: int) -> int:
        """Event-time promise for the outputs, given the inputs' watermark.

        Default: outputs carry the stamp of the input that caused them, so nothing older
        than the input watermark can follow.  A node that emits later than it reads
        (e.g. waiting for evidence) returns something smaller.
        """
        return input_watermark

    def close(self) -> None:
        """Release resources and save state (default: nothing)."""

    # ---- checkpoints (common.resume) ---------------------------------------------------
    #: attributes a checkpoint leaves out: rebuilt from the configuration by ``__init__``
    checkpoint_exclude: ClassVar[tuple[str, ...]] = ()
    _CHECKPOINT_NEVER = ("config", "inputs", "outputs", "_outbox")

    def checkpoint_state(self) -> dict[str, Any]:
        """The node's state for a checkpoint: every instance attribute (the algorithm core's
        objects, output seqs, counters) but the configuration and ``checkpoint_exclude``.
        The result is pickled; restoring it into a node built from the same configuration
        (:meth:`restore_checkpoint`) continues exactly where this one is."""
        skip = set(self._CHECKPOINT_NEVER) | set(self.checkpoint_exclude)
        return {k: v for k, v in vars(self).items() if k not in skip}

    def restore_checkpoint(self, state: dict[str, Any]) -> None:
        """Inverse of :meth:`checkpoint_state` on a node built from the same configuration."""
        unknown = set(state) - set(vars(self))
        if unknown:
            raise ValueError(f"{self.name}: checkpoint has attributes this node does not: {sorted(unknown)}")
        for k, v in state.items():
            setattr(self, k, v)

    # ---- helpers for subclasses ---------------------------------------------------
    def header(self, key: str, stamp: int, frame_id: str = "") -> Header:
        """Next header of output ``key``: per-key seq, the given event stamp."""
        seq = self._seq[key]
        self._seq[key] = seq + 1
        return Header(seq=seq, stamp=stamp, frame_id=frame_id)

    def publish(self, key: str, msg: Message) -> None:
        if key not in self._seq:
            raise KeyError(f"{self.name}: {key!r} is not one of its outputs {self.outputs}")
        self._outbox.append((key, msg))

    def count(self, what: str, n: int = 1) -> None:
        """Count an event of note (rejected records, gaps...) for the run summary."""
        self.counters[what] = self.counters.get(what, 0) + n

    def take_outbox(self) -> list[tuple[str, Message]]:
        out, self._outbox = self._outbox, []
        return out


def run_offline(node: ServiceNode[Any], messages: Iterable[tuple[str, Message]]) -> list[tuple[str, Message]]:
    """Drive ``node`` with ``(key, message)`` pairs without any transport.

    Messages are merged by event time exactly as the bus runtime does (each input key is
    assumed to arrive in its own order, as a recording or a publisher delivers it).
    Keys the node does not consume are ignored.  Returns every output in order.
    """
    merger = EventTimeMerger(list(node.inputs))
    for key, msg in messages:
        if key in node.inputs:
            merger.push(key, msg.header.stamp, msg.header.seq, msg)
    for key in node.inputs:
        merger.end(key)
    out: list[tuple[str, Message]] = []
    for key, _stamp, msg in merger.pop_ready():
        node.process(key, msg)
        out.extend(node.take_outbox())
    node.finish()
    out.extend(node.take_outbox())
    return out
