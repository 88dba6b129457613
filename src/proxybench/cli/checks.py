"""Printing a contract suite's report (`agent check`, `robot check`): one line per check, failures in red."""

from __future__ import annotations

from typing import TYPE_CHECKING

from rich.markup import escape

from proxybench.cli.app import console

if TYPE_CHECKING:
    from proxybench.testing import ContractReport


def print_report(report: ContractReport) -> bool:
    """Each check as ``✓ name: reason`` (``✗`` in red when it failed), then a summary line; whether all passed."""
    for r in report.results:
        mark = "[green]✓[/green]" if r.passed else "[red]✗[/red]"
        console.print(f"{mark} {escape(r.name)}: {escape(r.reason)} [dim]({r.seconds:.1f} s)[/dim]", highlight=False)
    failed = len(report.failures)
    console.print(f"{report.contract}: {len(report.results) - failed} of {len(report.results)} checks passed"
                  + (f", [red]{failed} failed[/red]" if failed else ""), highlight=False)
    return report.ok
