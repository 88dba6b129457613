"""Database engine and sessions: one factory for SQLite (embedded default) and PostgreSQL.

The schema is owned by Alembic migrations (``server/migrations``); :func:`migrate` brings any database
to the newest revision, so an existing server upgrades in place and nothing stored is lost.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from sqlalchemy import Engine, create_engine, event
from sqlalchemy.orm import Session, sessionmaker

__all__ = ["make_engine", "migrate", "session_scope"]

_MIGRATIONS = Path(__file__).with_name("migrations")


def make_engine(url: str, pool_size: int = 12, *, autocommit: bool = False, max_overflow: int = 8) -> Engine:
    """An engine tuned for a server with many short transactions from many threads.

    ``pool_size`` connections are always enough when at most ``pool_size`` sessions are open at once
    (the app admits fewer requests than that); a few more may be opened briefly by other callers.
    ``autocommit``: every statement commits on its own (no BEGIN / ROLLBACK round trips): for the
    server's reads, on connections of their own, so none is switched back and forth per request.
    """
    options = {"isolation_level": "AUTOCOMMIT"} if autocommit else {}
    if url.startswith("sqlite"):
        engine = create_engine(url, connect_args={"check_same_thread": False, "timeout": 30},
                               pool_size=pool_size, max_overflow=max_overflow, **options)

        @event.listens_for(engine, "connect")
        def _pragmas(conn, _record) -> None:  # WAL: readers never block the writer
            cur = conn.cursor()
            cur.execute("PRAGMA journal_mode=WAL")
            cur.execute("PRAGMA synchronous=NORMAL")
            cur.execute("PRAGMA foreign_keys=ON")
            cur.execute("PRAGMA busy_timeout=30000")
            cur.close()

        return engine
    # no pre-ping (a round trip per request); a connection that died with a database restart fails one
    # request (a 500, retried by clients) and SQLAlchemy then replaces the whole pool
    return create_engine(url, pool_size=pool_size, max_overflow=max_overflow, pool_recycle=3600, **options)


def migrate(engine: Engine) -> None:
    """Upgrade the database behind ``engine`` to the newest schema revision."""
    from alembic import command
    from alembic.config import Config

    cfg = Config()
    cfg.set_main_option("script_location", str(_MIGRATIONS))
    with engine.begin() as conn:
        cfg.attributes["connection"] = conn
        command.upgrade(cfg, "head")


@contextmanager
def session_scope(factory: sessionmaker[Session]) -> Iterator[Session]:
    """One unit of work: commit on success, roll back on any error (as Optuna's storages do)."""
    session = factory()
    try:
        yield session
        session.commit()
    except BaseException:
        session.rollback()
        raise
    finally:
        session.close()
