"""``poseidon vpr``: the command line of :mod:`eval.vpr` (arguments, the printed table, ``--json``);
the figures, their definitions and the JSON keys are in :mod:`eval.vpr`."""
from __future__ import annotations

import argparse
import json
import logging
import sys
from typing import TYPE_CHECKING, Any

from eval.results import LvcScores, MatcherMetrics, MissionResult
from eval.vpr import evaluate_image_sets, evaluate_mission, input_errors

if TYPE_CHECKING:
    from services.encoder.config import EncoderConfig
    from system.config import PoseidonConfig

__all__ = ["main"]


def _vpr_doc() -> str:
    import eval.vpr
    return eval.vpr.__doc__ or ""


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="poseidon vpr", description=_vpr_doc().split("\n\n")[0])
    ap.add_argument("--ref", default=None, help="reference image folder")
    ap.add_argument("--query", default=None, help="query image folder")
    ap.add_argument("--mission", default=None, metavar="FILE.mcap",
                    help="a recording with camera/image_raw, truth/revisits and truth/pose (instead of --ref/--query)")
    ap.add_argument("--min-gap-m", type=float, default=None,
                    help="--mission: earlier frames count as candidates only this far back along the track, m "
                         "(default: the recording's revisit_min_gap_m)")
    ap.add_argument("--gt", default="", help="VPR-Bench ground truth .npy (default: same file name)")
    ap.add_argument("--tolerance", type=int, default=0, help="same-name ground truth: +-N frames also match")
    ap.add_argument("--weights", default=None, help="torchvision state dict (default: encoder.weights_path)")
    ap.add_argument("--backbone", choices=["efficientnet_lite0", "shufflenetv2", "alexnet_conv3"], default=None)
    ap.add_argument("--limit", type=int, default=0, help="first N frames of each folder (0: all)")
    ap.add_argument("--config", default=None, help="PoseidonSLAM YAML configuration")
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--no-htm", action="store_true", help="skip the HTM matchers")
    ap.add_argument("--no-chains", action="store_true",
                    help="do not run the named chains (services/htm/chains.py: sdr_seqmem, no_tm, no_dr_gate, no_seqmem, sp_tm, sdr_seqmem_f1, "
                         "sdr_seqmem_cal, new_places) beside the default")
    ap.add_argument("--htm-query-learning", action="store_true",
                    help="keep HTM learning on during the query pass (default: off, fixed reference)")
    ap.add_argument("--save-norm", default=None, metavar="FILE.npz",
                    help="write the camera embedding statistics of the run (embedding_norm running/fixed) here, "
                         "e.g. for encoder.embedding_norm.mode fixed")
    ap.add_argument("--json", action="store_true", help="print the figures as one JSON object")
    return ap


def _print_lvc(name: str, r: LvcScores | MissionResult) -> None:
    d = r.get("decisions", {})
    print(f"{name:12s} LVC ids {r['n_lvc']}, per-frame revisit recall {r['lvc_recall']:.3f}, "
          f"precision {r['lvc_precision']:.3f}; SP columns used {r.get('sp_columns_used', 0)}; decisions "
          + ", ".join(f"{k} {v}" for k, v in d.items()) + f" (TM share {r.get('tm_decision_share', 0.0):.3f})")


def _print_table(title: str, metrics: dict[str, MatcherMetrics]) -> None:
    print(title)
    print(f"{'matcher':24s} {'AUC':>7s} {'R@P100':>7s} {'bestF1':>7s}")
    for name, m in metrics.items():
        print(f"{name:24s} {m['auc']:7.3f} {m['recall_at_p100']:7.3f} {m['best_f1']:7.3f}")


def _load_configs(args: argparse.Namespace) -> tuple[PoseidonConfig, EncoderConfig]:
    """The run configuration and its encoder section with the command line's overrides."""
    from system.config import load_config

    cfg = load_config(args.config, args.overrides)
    enc_cfg = cfg.encoder
    upd: dict[str, Any] = {}
    if args.weights is not None:
        upd["weights_path"] = args.weights
    if args.backbone is not None:
        upd["cnn_backbone"] = args.backbone
    if enc_cfg.embedding_norm.mode != "fixed":
        upd["embedding_norm.path"] = ""  # running statistics start fresh, in memory, every run
    return cfg, enc_cfg.updated(upd)


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``poseidon vpr`` (see the module docstring)."""
    args = _parser().parse_args(argv)
    errors = input_errors()
    if not logging.getLogger().handlers:
        logging.basicConfig(level=logging.WARNING, stream=sys.stderr, format="%(levelname)s %(message)s")
    if args.mission is None and (args.ref is None or args.query is None):
        print("poseidon vpr: give --ref DIR and --query DIR, or --mission FILE.mcap", file=sys.stderr)
        return 2
    if args.mission is not None and (args.ref is not None or args.query is not None):
        print("poseidon vpr: --mission excludes --ref/--query", file=sys.stderr)
        return 2
    from services.htm.chains import CHAINS
    chains = () if (args.no_htm or args.no_chains) else tuple(CHAINS)
    try:
        cfg, enc_cfg = _load_configs(args)
    except errors as exc:
        print(f"poseidon vpr: {exc}", file=sys.stderr)
        return 2
    if args.mission is not None:
        return _main_mission(args, cfg, enc_cfg, chains, errors)
    return _main_image_sets(args, cfg, enc_cfg, chains, errors)


def _main_mission(args: argparse.Namespace, cfg: PoseidonConfig, enc_cfg: EncoderConfig,
                  chains: tuple[str, ...], errors: tuple[type[Exception], ...]) -> int:
    """``poseidon vpr --mission``: figures of one recording, printed as a table or JSON."""
    try:
        result = evaluate_mission(args.mission, cfg, enc_cfg, args.min_gap_m, not args.no_htm, chains)
    except errors as exc:
        print(f"poseidon vpr: {exc}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        _print_table(f"VPR on mission {args.mission}: {result['n_frames']} frames, {result['n_revisit_frames']} "
                     f"revisits, backbone {enc_cfg.cnn_backbone} ({result['weights']} weights), "
                     f"embedding_norm {enc_cfg.embedding_norm.mode}", result["matchers"])
        if "lvc_recall" in result:
            _print_lvc("default", result)
            for cname, c in result.get("chains", {}).items():
                _print_lvc(cname, c)
    return 0


def _main_image_sets(args: argparse.Namespace, cfg: PoseidonConfig, enc_cfg: EncoderConfig,
                     chains: tuple[str, ...], errors: tuple[type[Exception], ...]) -> int:
    """``poseidon vpr --ref DIR --query DIR``: figures of the query folder against the reference."""
    try:
        result = evaluate_image_sets(args.ref, args.query, cfg, enc_cfg, limit=args.limit, gt_file=args.gt,
                                     tolerance=args.tolerance, save_norm=args.save_norm, htm=not args.no_htm,
                                     chains=chains, query_learning=args.htm_query_learning)
    except errors as exc:
        print(f"poseidon vpr: {exc}", file=sys.stderr)
        return 2
    metrics = result["matchers"]
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        _print_table(f"VPR {args.query} vs {args.ref}: {result['n_query']} queries, {result['n_ref']} references, "
                     f"backbone {result['backbone']} ({result['weights']} weights), ground truth {result['ground_truth']}, "
                     f"embedding_norm {enc_cfg.embedding_norm.mode}", metrics)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
