"""``calib data fetch`` and ``calib data list``: the reference camera collections."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.table import Table

from calib.core.datasets import (
    DATA_DIR_ENV,
    collection_status,
    default_data_dir,
    fetch_datasets,
    pinned_files,
)


def register(app: typer.Typer) -> None:
    data_app = typer.Typer(
        help="Reference camera sensitivity data (downloaded, never shipped).", no_args_is_help=True
    )

    @data_app.command("fetch")
    def fetch(
        dest: Annotated[
            Path | None, typer.Option(help="Data directory to fill (default: the user cache).")
        ] = None,
        collection: Annotated[
            list[str] | None, typer.Option(help="Collections to fetch (repeatable; default all).")
        ] = None,
        base_url: Annotated[
            str | None, typer.Option(help="Mirror root: {base}/{repo}/{commit}/{path}.")
        ] = None,
    ) -> None:
        """Download the pinned files from their public repositories and verify their SHA-256."""
        console = Console()
        files = pinned_files(collection)
        with console.status(f"fetching {len(files)} files…") as status:
            report = fetch_datasets(
                dest,
                collections=collection,
                base_url=base_url,
                progress=lambda done, total, path: status.update(f"{done}/{total} {path}"),
            )
        console.print(
            f"{len(report.downloaded)} downloaded, {len(report.already_present)} already present "
            f"and valid, in {report.destination}"
        )

    @data_app.command("list")
    def list_collections(
        data_dir: Annotated[Path | None, typer.Option(help="Data directory to inspect.")] = None,
    ) -> None:
        """Show each downloadable collection and how many of its files are present and valid."""
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
