"""The distribution ships every package and data file of the source tree: a subpackage or data file left out of
pyproject.toml works in the editable checkout and is missing from an installed copy."""

import tomllib
from fnmatch import fnmatch
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CONFIG = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
TOP = ("brdf", "skin_bssrdf", "stage", "relight")


def _source_packages() -> set[str]:
    found = set()
    for top in TOP:
        for init in (ROOT / top).rglob("__init__.py"):
            found.add(".".join(init.parent.relative_to(ROOT).parts))
    return found


def test_every_package_is_listed():
    listed = set(CONFIG["packages"])
    missing = _source_packages() - listed
    assert not missing, f"pyproject.toml [tool.setuptools] packages lacks {sorted(missing)}"


def test_every_data_file_matches_a_package_data_pattern():
    data = CONFIG["package-data"]
    unshipped = []
    for package, patterns in data.items():
        folder = ROOT.joinpath(*package.split("."))
        for f in folder.iterdir():
            if f.is_file() and f.name != "__init__.py" and not f.name.endswith(".pyc"):
                if not any(fnmatch(f.name, p) for p in patterns):
                    unshipped.append(str(f.relative_to(ROOT)))
    assert not unshipped, f"no package-data pattern ships {unshipped}"
