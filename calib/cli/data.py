"""``data fetch`` and ``data list`` (in ``calib`` and in ``rig`` alike): the reference camera collections.

The module imports the datasets lazily, inside the commands: ``rig`` registers these commands at
start-up.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from calib.cli.command_line import new_app
from calib.cli.options import QuietOption

DataDirToFill = Annotated[
    Path | None,
    typer.Option(
        "--data-dir",
        metavar="DIR",
        help="The data directory (default: $SPECTRAL_RIG_DATA, else the user cache).",
    ),
]


def register(app: typer.Typer) -> None:
    """Add the ``data`` group (``fetch``, ``list``) to ``app``."""
    data_app = new_app(
        "data",
        "Reference camera sensitivity data (downloaded; rawtoaces-data ships with spectral-rig).",
    )

    @data_app.command("fetch")
    def fetch(
        data_dir: DataDirToFill = None,
        collection: Annotated[
            list[str] | None,
            typer.Option(
                metavar="NAME",
                help="A collection to fetch (repeatable; default all): {fetchable_collections}.",
            ),
        ] = None,
        base_url: Annotated[
            str | None,
            typer.Option(
                metavar="URL",
                help="Mirror root: {base}/{repository}/{commit}/{path}; file:// works.",
            ),
        ] = None,
        quiet: QuietOption = False,
    ) -> None:
        """Download the pinned camera collections and verify every file's size and SHA-256."""
        from rich.console import Console
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn

        from calib.core.datasets import fetch_datasets, pinned_files
        from calib.core.errors import InputError

        try:
            files = pinned_files(collection)
        except InputError as exc:
            raise InputError(
                str(exc).removeprefix(f"{exc.source}: "), source="--collection"
            ) from None
        progress = Progress(
            TextColumn("fetching"),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn("{task.description}"),
            console=Console(stderr=True),
            disable=quiet,
        )
        with progress:
            task = progress.add_task("", total=len(files))

            def advance(done: int, total: int, path: str) -> None:
                progress.update(task, completed=done, total=total, description=path)

            report = fetch_datasets(
                data_dir, collections=collection, base_url=base_url, progress=advance
            )
        typer.echo(
            f"{len(report.downloaded)} downloaded, {len(report.already_present)} already present "
            f"and valid, in {report.destination}"
        )

    @data_app.command("list")
    def list_collections(data_dir: DataDirToFill = None) -> None:
        """Show each downloadable collection and how many of its files are present and valid."""
        from rich.console import Console
        from rich.table import Table

        from calib.core.datasets import DATA_DIR_ENV, collection_status, default_data_dir

        table = Table(
            title=f"camera data in {data_dir or f'${DATA_DIR_ENV} or {default_data_dir()}'}"
        )
        table.add_column("collection")
        table.add_column("valid files", justify="right")
        for name, (valid, total) in collection_status(data_dir).items():
            colour = "green" if valid == total else "yellow" if valid else "red"
            table.add_row(name, f"[{colour}]{valid}/{total}[/{colour}]")
        Console().print(table)

    app.add_typer(data_app, name="data")
