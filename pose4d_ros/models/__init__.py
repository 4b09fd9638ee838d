"""Shipped, trained part models (.npz) and their training notes (README.md)."""

from __future__ import annotations

from pathlib import Path

MODELS_DIR = Path(__file__).resolve().parent
# The photograph network the detector runs in its colour unary by default, and its arithmetic
# (`core.dpm.net_unary`; the detector node's detector.colour_net, `pose4d eval --colour-net`)
DEFAULT_COLOUR_NET = 'lspet_convnet'
DEFAULT_NET_PRECISION = 'int8'


def shipped_models() -> list[str]:
    """Names of the models shipped with the package."""
    return sorted(p.stem for p in MODELS_DIR.glob('*.npz'))


def model_path(name_or_path: str | Path) -> Path:
    """The .npz of a shipped model name ('rgbd_10') or an existing path."""
    path = Path(name_or_path)
    if path.suffix == '.npz' or path.parent != Path('.'):
        if not path.is_file():
            raise FileNotFoundError(f'{path}: no such model file')
        return path
    shipped = MODELS_DIR / f'{name_or_path}.npz'
    if not shipped.is_file():
        raise FileNotFoundError(f'no shipped model named {name_or_path!r} (shipped: '
                                f'{", ".join(shipped_models()) or "none"})')
    return shipped
