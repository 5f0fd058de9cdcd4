"""The real-building corpus of a checkout (``data/ifc_corpus/``): its manifest and where each file lives.

``manifest.json`` lists every file with its source, sha256, licence and split (train or held
out); only the duplex ships (``tests/data/ifc/duplex.ifc``), the others are fetched into
``data/ifc_corpus/files/`` (``python benchmarks/fetch_ifc_corpus.py``). Used by the corpus
weights (:mod:`uav_struct_env.training.corpus_weights`) and the corpus benchmarks.
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["CORPUS", "MANIFEST", "REPO", "corpus_file"]

#: The repository's root (a checkout: the corpus is not part of an installed package).
REPO = Path(__file__).resolve().parents[2]
#: The corpus folder.
CORPUS = REPO / "data" / "ifc_corpus"
#: The corpus manifest.
MANIFEST = CORPUS / "manifest.json"


def corpus_file(entry: dict, files: str | Path | None = None) -> Path:
    """Where the manifest entry's file lives on this machine (it may not exist).

    ``files/<name>.ifc`` when ``files`` is given and holds it, else the entry's ``local_path``
    (relative to the repository root unless absolute; where the shipped duplex lives).
    """
    if files is not None and (Path(files) / f"{entry['name']}.ifc").exists():
        return Path(files) / f"{entry['name']}.ifc"
    p = Path(entry["local_path"])
    return p if p.is_absolute() else REPO / p
