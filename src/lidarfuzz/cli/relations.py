"""``lidarfuzz relations``: the metamorphic relations and their parameters."""

from typing import Annotated, Any

import typer

from lidarfuzz.cli.common import Column, JsonOption, PlainOption, console, print_listing, print_table


def relations_command(
    name: Annotated[str | None, typer.Argument(help="Show one relation's parameters.")] = None,
    as_json: JsonOption = False,
    plain: PlainOption = False,
) -> None:
    """List the metamorphic relations: what each checks, the operators it applies to, its parameters."""
    from lidarfuzz.oracles.relations import available, get

    if name is not None:
        cls = get(name)
        fields = [(info.alias or field, info) for field, info in cls.ConfigModel.model_fields.items()]
        if as_json or plain:
            record = {**_record(cls), "parameters": [{"name": shown, "default": info.default,
                                                      "description": info.description or ""}
                                                     for shown, info in fields]}
            parameter_rows = [[shown, repr(info.default), info.description or ""] for shown, info in fields]
            print_listing([], parameter_rows, record, as_json=as_json, plain=plain)
            return
        from rich.table import Table

        console.print(f"[bold]{cls.name}[/] — {cls.description}")
        console.print(f"applies to {', '.join(sorted(r.value for r in cls.applies_to))} operators")
        table = Table("parameter", "default", "description")
        table.columns[0].no_wrap, table.columns[0].overflow = True, "fold"
        for shown, info in fields:
            table.add_row(shown, repr(info.default), info.description or "")
        print_table(table)
        return
    rows: list[list[str]] = []
    records: list[dict[str, Any]] = []
    for rel_name, cls in sorted(available().items()):
        rows.append([rel_name, ", ".join(sorted(r.value for r in cls.applies_to)), cls.description])
        records.append({**_record(cls), "name": rel_name})
    print_listing([Column("name", name=True), Column("applies to"), Column("checks")], rows, records,
                  as_json=as_json, plain=plain, footer="details: [cyan]lidarfuzz relations NAME[/]; "
                                                       "the guide: docs/oracles.md")


def _record(cls: Any) -> dict[str, Any]:
    return {"name": cls.name, "applies_to": sorted(r.value for r in cls.applies_to), "checks": cls.description}
