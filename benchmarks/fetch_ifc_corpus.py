"""Download the corpus files that are not shipped (data/ifc_corpus/manifest.json) and check them.

    .venv/bin/python benchmarks/fetch_ifc_corpus.py [--only-missing] [--names tekla_carwash ...]

Each file is fetched from ``https://raw.githubusercontent.com/<repository>/<commit>/<path>`` (the
manifest's ``url``), written to its ``local_path`` (data/ifc_corpus/files/<name>.ifc) only when its
sha256 matches the manifest, and reported otherwise. Shipped files are checked, not downloaded.

It needs a machine that reaches GitHub: this project's development machines and CI reach only the
package registries, so here it reports every download as failed (nothing depends on it: tests use
shipped files only). The downloaded files stay outside version control; their licences (GPL, MPL,
CDDL or none stated) do not allow shipping them with this repository.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import urllib.error
import urllib.request
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MANIFEST = ROOT / "data" / "ifc_corpus" / "manifest.json"


def _sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def main(manifest: str | Path = MANIFEST, only_missing: bool = True, names: list[str] | None = None,
         timeout: float = 60.0) -> dict[str, str]:
    """Fetch and verify; return {name: status} (ok, present, downloaded, or what went wrong)."""
    entries = json.loads(Path(manifest).read_text())["files"]
    status: dict[str, str] = {}
    for e in entries:
        if names and e["name"] not in names:
            continue
        dest = ROOT / e["local_path"]
        if dest.exists():
            good = _sha256(dest.read_bytes()) == e["sha256"]
            status[e["name"]] = "present" if good else "present, sha256 MISMATCH"
            if good or e["shipped"] or only_missing:
                print(f"{e['name']:<22} {status[e['name']]}")
                continue
        if e["shipped"]:
            status[e["name"]] = "shipped file missing from the checkout"
            print(f"{e['name']:<22} {status[e['name']]}")
            continue
        try:
            with urllib.request.urlopen(e["url"], timeout=timeout) as r:  # noqa: S310 (fixed https URL)
                data = r.read()
        except (urllib.error.URLError, OSError) as exc:
            status[e["name"]] = f"download failed: {type(exc).__name__}: {exc}"
        else:
            if _sha256(data) != e["sha256"]:
                status[e["name"]] = f"sha256 mismatch ({len(data)} bytes), not written"
            else:
                dest.parent.mkdir(parents=True, exist_ok=True)
                dest.write_bytes(data)
                status[e["name"]] = f"downloaded ({len(data) / 1e6:.1f} MB)"
        print(f"{e['name']:<22} {status[e['name']]}")
    return status


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                     formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    parser.add_argument("--manifest", default=str(MANIFEST), help="the corpus manifest")
    parser.add_argument("--only-missing", action=argparse.BooleanOptionalAction, default=True,
                        help="leave a present file alone even if its sha256 differs (it is reported)")
    parser.add_argument("--names", nargs="*", default=None, help="only these corpus names")
    parser.add_argument("--timeout", type=float, default=60.0, help="seconds per download")
    args = parser.parse_args()
    main(manifest=args.manifest, only_missing=args.only_missing, names=args.names, timeout=args.timeout)
