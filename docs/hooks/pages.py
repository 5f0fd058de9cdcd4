"""MkDocs hooks: generated text in the pages, and docstring cross-references made readable.

* ``<!-- generated: env-settings -->`` in a page becomes the table of every environment setting
  (:func:`uav_struct_env.envs.settings.settings_markdown`); an undocumented setting raises there
  and fails the build.
* The code's docstrings name objects with reST roles (``:class:`~a.b.C```), which mkdocstrings
  renders as text; they are shown as code (``C``) instead.
"""

from __future__ import annotations

import re

from uav_struct_env.envs.settings import settings_markdown

GENERATORS = {"<!-- generated: env-settings -->": settings_markdown}

_ROLE = re.compile(r":(?:py:)?(?:meth|class|func|mod|data|attr|exc|obj|const):<code>(~?)([\w.]+)</code>")


def on_page_markdown(markdown: str, page, config, files) -> str:  # noqa: ARG001 (MkDocs signature)
    """Replace every generator marker in the page by its generated text."""
    for marker, generate in GENERATORS.items():
        if marker in markdown:
            markdown = markdown.replace(marker, generate())
    return markdown


def on_page_content(html: str, page, config, files) -> str:  # noqa: ARG001 (MkDocs signature)
    """``:class:`~a.b.C``` rendered by mkdocstrings as text becomes ``C`` in code."""
    return _ROLE.sub(lambda m: f"<code>{m.group(2).rsplit('.', 1)[-1] if m.group(1) else m.group(2)}</code>",
                     html)
