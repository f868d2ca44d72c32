"""mkdocs hook: publish the command reference generated from kinefuse's parsers."""

from mkdocs.structure.files import File

from kinefuse.app.cli.cli_reference import render


def on_files(files, config):  # noqa: ANN001, ANN201 (mkdocs' hook signature)
    files.append(File.generated(config, "reference/cli.md", content=render()))
    return files
