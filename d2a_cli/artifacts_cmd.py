"""`d2a artifacts`: list, inspect, verify, garbage-collect and tag stored artifacts."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Optional

import typer
from rich.table import Table
from rich.tree import Tree

from d2a_cli.common import RunContext, err_console, out_console, report_error, with_common_options
from d2a_core.errors import IntegrityError

app = typer.Typer(help="Inspect and maintain the artifact store.", no_args_is_help=True)


def _human_size(n: int) -> str:
    for unit in ("B", "KiB", "MiB", "GiB"):
        if n < 1024 or unit == "GiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    return str(n)


@app.command("ls")
@with_common_options
def ls(
    kind: Annotated[Optional[str], typer.Option("--kind", help="Only artifacts of this kind.")] = None,
    *,
    run: RunContext,
) -> None:
    """List stored artifacts, oldest first."""
    store = run.store()
    refs = store.refs()
    unreadable: list[str] = []
    arts = store.list(kind, unreadable=unreadable)
    rows = [
        {
            "id": art.id,
            "kind": art.kind,
            "created": art.created,
            "size": art.size,
            "aliases": [a for a, t in refs.items() if t == art.id],
            "labels": art.labels,
        }
        for art in arts
    ]
    if unreadable:  # one damaged manifest must not hide the rest of the store
        err_console.print(f"[yellow]warning:[/] {len(unreadable)} manifest(s) cannot be read and are not listed: "
                          f"{', '.join(i[:12] for i in unreadable)}; see d2a artifacts verify", highlight=False)

    def render(result: dict[str, Any]) -> None:
        table = Table(title=f"artifacts in {store.root}", title_justify="left")
        for col in ("id", "kind", "created", "size", "aliases"):
            table.add_column(col)
        for row in result["artifacts"]:
            table.add_row(row["id"][:12], row["kind"], row["created"][:19], _human_size(row["size"]),
                          ", ".join(row["aliases"]))
        out_console.print(table)

    run.emit({"store": str(store.root), "artifacts": rows, "unreadable": unreadable}, render)


def _tree(node: dict[str, Any], tree: Tree) -> None:
    for child in node.get("inputs", []):
        label = f"{child['id'][:12]} [dim]{child['kind']}[/]"
        if child.get("aliases"):
            label += f" ({', '.join(child['aliases'])})"
        if child.get("shared"):
            label += " [dim](shown above)[/]"
        _tree(child, tree.add(label))


@app.command("show")
@with_common_options
def show(
    ref: Annotated[str, typer.Argument(help="Artifact id, unique id prefix or alias.")],
    *,
    run: RunContext,
) -> None:
    """Show an artifact's manifest and its lineage (inputs, recursively)."""
    store = run.store()
    art = store.get(ref)
    result = {
        "id": art.id,
        "aliases": store.aliases_of(art.id),
        "manifest": art.manifest,
        "lineage": store.lineage(art.id),
    }

    def render(result: dict[str, Any]) -> None:
        m = result["manifest"]
        out_console.print(f"[bold]{art.id}[/]  kind={m['kind']}  seed={m['seed']}")
        if result["aliases"]:
            out_console.print(f"aliases: {', '.join(result['aliases'])}")
        prov = m["provenance"]
        code = prov["code"]
        out_console.print(f"created {prov['created']}  code {code['version']} {code['git_commit'] or ''}"
                          f"{' (dirty)' if code['dirty'] else ''}")
        out_console.print(f"command: {' '.join(prov['command'])}")
        if m["labels"]:
            out_console.print(f"labels: {m['labels']}")
        files = Table("file", "size", "sha256")
        for name, info in sorted(m["files"].items()):
            files.add_row(name, _human_size(info["size"]), info["sha256"][:16])
        out_console.print(files)
        tree = Tree(f"[bold]lineage[/] {art.id[:12]} {m['kind']}")
        _tree(result["lineage"], tree)
        out_console.print(tree)

    run.emit(result, render)


@app.command("verify")
@with_common_options
def verify(
    refs: Annotated[Optional[list[str]], typer.Argument(help="Artifacts to check (default: all).")] = None,
    repair: Annotated[bool, typer.Option(
        "--repair", help="Move what cannot be used (unreadable manifests and alias files, corrupted blobs, "
                         "aliases to missing artifacts) into quarantine/ so every command works again; "
                         "rebuilding an artifact then restores it.")] = False,
    *,
    run: RunContext,
) -> None:
    """Re-hash every blob and manifest; exit 3 naming each corrupted artifact and alias."""
    store = run.store()
    checked = len(refs) if refs else store.count()
    problems = store.verify(refs or None, repair=repair)
    unrepaired = [p for p in problems if not p.repaired]
    result = {"checked": checked, "ok": not problems, "repaired": sum(1 for p in problems if p.repaired),
              "problems": [p.as_dict() for p in problems]}

    def render(result: dict[str, Any]) -> None:
        if result["ok"]:
            out_console.print(f"[green]ok[/]: {checked} artifacts verified")
        for p in problems:
            if p.repaired:
                out_console.print(f"repaired {p.alias or p.artifact or p.path}: {p.what}: {p.repaired}",
                                  highlight=False)

    run.emit(result, render)
    if unrepaired or (problems and not repair):
        # the JSON result above already lists the problems; stderr gets the human version
        lines = [f"{p.artifact or p.alias or '-'}: {p.what}" for p in unrepaired]
        report_error(f"{len(unrepaired)} problem(s) in store {store.root}:\n  " + "\n  ".join(lines)
                     + ("" if repair else "\n(d2a artifacts verify --repair quarantines what cannot be read)"),
                     IntegrityError.exit_code, "IntegrityError", json_too=False)
        raise typer.Exit(IntegrityError.exit_code)


@app.command("gc")
@with_common_options
def gc(
    dry_run: Annotated[bool, typer.Option("--dry-run", help="Report what would be removed; remove nothing.")] = False,
    *,
    run: RunContext,
) -> None:
    """Remove artifacts nothing reaches (directly or as an input), their blobs and temp files.

    Kept: what an alias, a running command (its lease) or a run's saved state (runs/KEY/holds.json)
    reaches. If one of those cannot be read, gc removes nothing and exits 3 naming it.
    """
    report = run.store().gc(dry_run=dry_run)

    def render(result: dict[str, Any]) -> None:
        verb = "would remove" if dry_run else "removed"
        out_console.print(f"{verb} {len(result['artifacts'])} artifacts, {result['blobs']} blobs, "
                          f"{result['temp_files']} temp files ({_human_size(result['bytes_freed'])})")
        for root, ids in result["held"].items():
            out_console.print(f"kept for {root}: {len(ids)} artifact(s)", highlight=False)

    run.emit(report.as_dict(), render)


@app.command("tag")
@with_common_options
def tag(
    ref: Annotated[str, typer.Argument(help="Artifact id, unique id prefix or alias.")],
    alias: Annotated[str, typer.Argument(help="Alias to set, e.g. track/hairpin.")],
    *,
    run: RunContext,
) -> None:
    """Point ALIAS at an artifact (replacing the alias's old target)."""
    art_id = run.store().tag(ref, alias)
    run.emit({"alias": alias, "id": art_id}, lambda r: out_console.print(f"{alias} -> {art_id}"))


@app.command("export")
@with_common_options
def export(
    ref: Annotated[str, typer.Argument(help="Artifact id, unique id prefix or alias.")],
    directory: Annotated[Path, typer.Argument(help="Directory to copy the artifact's files into.")],
    *,
    run: RunContext,
) -> None:
    """Copy an artifact's files under their own names (e.g. a replay.mcap to open in Foxglove)."""
    store = run.store()
    art_id = store.resolve(ref)
    paths = store.export(art_id, directory)
    run.emit({"id": art_id, "files": [str(p) for p in paths]},
             lambda r: [out_console.print(p, highlight=False) for p in r["files"]])


@app.command("pack")
@with_common_options
def pack(
    refs: Annotated[list[str], typer.Argument(help="Artifacts to pack (ids, unique id prefixes or aliases).")],
    out: Annotated[Path, typer.Option("--out", "-o", help="Bundle file to write (a tar file).")],
    *,
    run: RunContext,
) -> None:
    """Write artifacts with everything they were made from (their lineage) and the aliases that
    name them into one file that `d2a artifacts import` takes into another store."""
    from d2a_core.artifacts.bundle import pack as pack_bundle

    result = pack_bundle(run.store(), refs, out)
    run.emit(result, lambda r: out_console.print(
        f"{r['bundle']}: {r['artifacts']} artifacts, {r['files']} files, {_human_size(r['bytes'])}", highlight=False))


@app.command("import")
@with_common_options
def import_(
    bundle: Annotated[Path, typer.Argument(help="Bundle file written by d2a artifacts pack.")],
    *,
    run: RunContext,
) -> None:
    """Take a bundle into this store. Every file name, hash and checkpoint is checked before
    anything is written: a damaged or tampered bundle, or a checkpoint that would run code when
    loaded, is refused (exit 3) and the store is left as it was. Aliases the store already uses
    for other artifacts are kept."""
    from d2a_core.artifacts.bundle import unpack
    from d2a_core.training.torch_files import check_shared_file

    result = unpack(run.store(), bundle, check_shared_file)

    def render(r: dict[str, Any]) -> None:
        out_console.print(f"imported {r['imported']} artifacts ({r['already_present']} already here); roots: "
                          + ", ".join(i[:12] for i in r["roots"]), highlight=False)
        for alias, target in r["aliases"].items():
            out_console.print(f"{alias} -> {target[:12]}", highlight=False)
        for alias, current in r["aliases_kept"].items():
            err_console.print(f"alias {alias} kept: it names {current[:12]} here", highlight=False)

    run.emit(result, render)
