"""Our datasets in other tools' formats: :func:`export_minari` writes D_e / D_ca as a Minari dataset
(``navformer export minari``; the optional extra ``navformer_rl[minari]``), and
:func:`minari_replay_buffer` opens one with TorchRL's ``MinariExperienceReplay`` (working around TorchRL
0.14.1 serving zeros).

Names are imported lazily, so importing the package imports neither minari nor torch.
"""

from __future__ import annotations

from navformer_rl.utils.lazy import lazy_exports

_EXPORTS = {
    "MinariNotInstalledError": "navformer_rl.export.minari",
    "export_minari": "navformer_rl.export.minari",
    "minari_replay_buffer": "navformer_rl.export.torchrl_replay",
    "minari_spaces": "navformer_rl.export.minari",
    "parse_minari_id": "navformer_rl.export.minari",
}

__all__ = sorted(_EXPORTS)

__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
