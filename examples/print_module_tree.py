"""Print NavFormer's module tree, part by part, with the TensorDict keys each part reads and writes.

``make_navformer_actor(model)`` is a ``TensorDictSequential`` of three ``TensorDictModule``s: the dual
visual encoder, the causal transformer and the action head. ``--ablation`` shows how an ablation of Table IV
or the DT baseline is composed (``no_fs``, ``dt``, ...); ``--full`` prints torch's whole repr.

    .venv/bin/python examples/print_module_tree.py --ablation dt
"""

from __future__ import annotations

import argparse

from tensordict.nn import TensorDictModule
from torch import nn

from navformer_rl.modules import MODEL_ABLATIONS, NavFormerConfig, NavFormerModel, make_navformer_actor


def keys(module: TensorDictModule, which: str) -> str:
    return ", ".join(str(key) for key in getattr(module, which))


def count(module: nn.Module) -> str:
    return f"{sum(p.numel() for p in module.parameters()):,} parameters"


def print_tree(model: NavFormerModel) -> None:
    actor = make_navformer_actor(model)
    print(f"{type(actor).__name__}  ({count(actor)})")
    for part in actor:
        print(f"  {type(part.module).__name__}  ({count(part.module)})")
        print(f"    reads:  {keys(part, 'in_keys')}")
        print(f"    writes: {keys(part, 'out_keys')}")
        for name, child in part.module.named_children():
            print(f"    .{name}: {type(child).__name__}  ({count(child)})")
        if next(part.module.children(), None) is None:
            print(f"    {part.module.extra_repr()}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ablation", choices=MODEL_ABLATIONS, default="none")
    parser.add_argument("--full", action="store_true", help="print torch's repr of the whole actor")
    args = parser.parse_args()
    model = NavFormerModel(NavFormerConfig.ablation(args.ablation))
    print(f"{args.ablation}:")
    print_tree(model)
    if args.full:
        print(make_navformer_actor(model))


if __name__ == "__main__":
    main()
