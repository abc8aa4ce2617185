"""``lidarfuzz relations``: the metamorphic relations and their parameters."""

from __future__ import annotations

from typing import Annotated

import typer
from rich.table import Table


def register(app: typer.Typer) -> None:
    @app.command("relations")
    def relations_command(
        name: Annotated[str | None, typer.Argument(help="Show one relation's parameters.")] = None,
    ) -> None:
        """List the metamorphic relations: what each checks, the operators it applies to, its parameters."""
        from lidarfuzz.cli.app import console
        from lidarfuzz.oracles.relations import available, get

        if name is not None:
            cls = get(name)
            console.print(f"[bold]{cls.name}[/] — {cls.description}")
            console.print(f"applies to {', '.join(sorted(r.value for r in cls.applies_to))} operators")
            table = Table("parameter", "default", "description")
            for field, info in cls.ConfigModel.model_fields.items():
                table.add_row(info.alias or field, repr(info.default), info.description or "")
            console.print(table)
            return
        table = Table("name", "applies to", "checks")
        for rel_name, cls in sorted(available().items()):
            table.add_row(rel_name, ", ".join(sorted(r.value for r in cls.applies_to)), cls.description)
        console.print(table)
        console.print("details: [cyan]lidarfuzz relations NAME[/]; the guide: docs/oracles.md")
