"""MkDocs hook: the command-line reference page, written from the argparse parser at every build.

``reference/cli.md`` is not a file of the repository: it is generated here from
``bench.cli.build_parser()`` (by :func:`bench.docs.cli_reference`), so it cannot drift from the
commands it documents.
"""

from __future__ import annotations

from mkdocs.structure.files import File

from bench.cli import build_parser
from bench.docs import cli_reference

CLI_PAGE = "reference/cli.md"


def on_files(files, config):
    files.append(File.generated(config, CLI_PAGE, content=cli_reference(build_parser())))
    return files
