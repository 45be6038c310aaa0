"""``poseidon config``: explain a configuration key, or show the effective configuration.

- ``poseidon config --explain KEY``: a field's dotted name, description, type, default, unit
  and allowed range; for a section (``htm.sp``, or ``''`` for the whole), its fields and
  sub-sections; for a key that was renamed, its new name (and the new key explained). Exit 2
  for an unknown key, naming the closest keys there are.
- ``poseidon config --show [--config FILE] [--set KEY=VALUE ...]``: the effective
  configuration as YAML (every field, defaults included). Exit 2 on a bad configuration.

The answers come from :func:`system.config.explain_key` and :func:`system.config.show_config`;
this module only prints them.
"""
from __future__ import annotations

import argparse
import json
import sys
from typing import Any

__all__ = ["add_arguments", "cmd_config"]


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``poseidon config`` (``--config``/``--set`` are added by the launcher)."""
    what = p.add_mutually_exclusive_group(required=True)
    what.add_argument("--explain", metavar="KEY", help="explain a configuration key (dotted, e.g. "
                      "htm.sp.num_active_columns; a section such as htm.sp lists its fields)")
    what.add_argument("--show", action="store_true", help="print the effective configuration as YAML")


def _value(value: Any) -> str:
    return json.dumps(value)


def _print_field(doc: Any) -> None:
    print(doc.key)
    print(f"  {doc.description}")
    print(f"  type:    {doc.type}")
    print(f"  default: {_value(doc.default)}")
    print(f"  unit:    {doc.unit or '-'}")
    print(f"  range:   {doc.range or '-'}")


def _print_section(doc: Any) -> None:
    print(f"{doc.key or '(the whole configuration)'}: {doc.description}")
    for f in doc.fields:
        unit = f" [{f.unit}]" if f.unit else ""
        print(f"  {f.key} = {_value(f.default)}{unit}  -- {f.description}")
    for s in doc.sections:
        print(f"  {s}: (section)")


def cmd_config(args: argparse.Namespace) -> int:
    """Exit 0: explained or shown; 2: unknown key or bad configuration."""
    from system.config import ConfigError, RenamedDoc, SectionDoc, UnknownKey, explain_key, load_config, show_config

    if args.show:
        try:
            config = load_config(args.config, args.set)
        except ConfigError as exc:
            print(f"poseidon config: {exc}", file=sys.stderr)
            return 2
        sys.stdout.write(show_config(config))
        return 0
    if args.config or args.set:
        print("poseidon config: --explain describes the keys; --config/--set apply to --show only",
              file=sys.stderr)
    try:
        doc = explain_key(args.explain)
        if isinstance(doc, RenamedDoc):
            print(f"{doc.key} was renamed {doc.new_key}\n")
            doc = explain_key(doc.new_key)
    except UnknownKey as exc:
        print(f"poseidon config: {exc}", file=sys.stderr)
        return 2
    if isinstance(doc, SectionDoc):
        _print_section(doc)
    else:
        _print_field(doc)
    return 0
