"""``ratslam_lv`` service: the RatSLAM local-view front-end (Table 3.1) as a swappable service.

Input ``ratslam_lv.image_topic`` (default ``camera/image_raw``), output
``local_view_cells`` (:class:`common.messages.LocalViewCells`, the same stream the HTM
front-end publishes), one message per valid frame with the frame's stamp and frame_id:

- ``most_active_cell`` = ``active_cells[0].id`` = the view-cell (template) id;
- ``active_cells[0].rate`` = ``1 - d / vt_match_threshold`` for a match with mean absolute
  difference d, 1 for a new template (:mod:`services.ratslam_lv.matcher`);
- ``is_new`` = the template was created on this frame;
- ``intersection`` = 0 (an HTM quantity, Eq. 4.6; RatSLAM has no SDR overlap).

A frame the matcher cannot use (empty, wrong crop for its size, unknown encoding) is
logged with its key and seq, counted (``frame_rejected``) and skipped.  Counters:
``templates_created``, ``templates_matched``, ``frame_rejected``.

How to run the back-end on it instead of the neocortical front-end (encoder + htm): the
launcher knows it as an optional service (not started by default, since it publishes the
same key as ``htm``), so name the services explicitly::

    poseidon run --input M.mcap --out R.mcap --services ratslam_lv,robot_state[,posecells,expmap]
    poseidon run --input M.mcap --out R.mcap --set 'services=[ratslam_lv,robot_state]'
    poseidon service ratslam_lv --connect tcp/HOST:7447      # on another computer

or replace the HTM implementation in a configuration file (then ``encoder`` still runs,
uselessly): ``service_classes: {htm: "services.ratslam_lv.node:RatSlamViewNode"}``.
Parameters: the ``ratslam_lv`` section of ``deploy/poseidon.yaml``.
"""
from __future__ import annotations

import logging

from common.messages import Image, LocalViewCell, LocalViewCells, Message
from common.node import ServiceNode
from services.ratslam_lv.config import RatSlamLvConfig
from services.ratslam_lv.matcher import LocalViewMatcher

__all__ = ["RatSlamViewNode"]

log = logging.getLogger(__name__)


class RatSlamViewNode(ServiceNode[RatSlamLvConfig]):
    """Runs :class:`LocalViewMatcher` on every camera frame."""

    name = "ratslam_lv"
    inputs = ("camera/image_raw",)
    outputs = ("local_view_cells",)

    @classmethod
    def io_keys(cls, config: RatSlamLvConfig) -> tuple[tuple[str, ...], tuple[str, ...]]:
        """Input and output keys under ``config`` (the launcher plans the run with them)."""
        return (config.image_topic,), cls.outputs

    def __init__(self, config: RatSlamLvConfig):
        super().__init__(config)
        self.cfg = config
        self.matcher = LocalViewMatcher(self.cfg)

    def process(self, key: str, msg: Message) -> None:
        if not isinstance(msg, Image):
            raise TypeError(f"ratslam_lv: {key!r} carries {type(msg).__name__}, expected Image")
        try:
            res = self.matcher.step(msg.data, msg.encoding)
        except ValueError as exc:
            log.error("ratslam_lv: %s seq %d skipped: %s", key, msg.header.seq, exc)
            self.count("frame_rejected")
            return
        self.count("templates_created" if res.is_new else "templates_matched")
        self.publish("local_view_cells", LocalViewCells(
            header=self.header("local_view_cells", msg.header.stamp, msg.header.frame_id),
            most_active_cell=res.view_id,
            active_cells=[LocalViewCell(id=res.view_id, rate=res.rate)],
            is_new=res.is_new,
            intersection=0,
        ))
