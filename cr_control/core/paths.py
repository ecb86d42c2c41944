"""Where the package's shipped files are: share/cr_control when installed, else the source tree."""

from __future__ import annotations

from pathlib import Path

_SOURCE_CONFIG = Path(__file__).resolve().parents[2] / "config"


def config_dir() -> Path:
    """Directory of the params files and the URDF."""
    if _SOURCE_CONFIG.is_dir():
        return _SOURCE_CONFIG
    try:
        from ament_index_python.packages import get_package_share_directory

        return Path(get_package_share_directory("cr_control")) / "config"
    except (ImportError, LookupError, OSError) as exc:
        raise FileNotFoundError("cannot find cr_control's config directory") from exc


def config_file(name: str) -> Path:
    """A file of the config directory (FileNotFoundError naming it if absent)."""
    path = config_dir() / name
    if not path.is_file():
        raise FileNotFoundError(f"no config file {path}")
    return path
