"""Alembic environment of the nutribench results database.

Programmatic use (what nutribench does): the caller puts an open connection, already inside
its transaction, in ``config.attributes["connection"]``. Command-line use:
``alembic -x db=PATH_OR_URL upgrade head`` (default ``nutribench.db``).
"""

from __future__ import annotations

import logging.config

from alembic import context

from nutribench.store.engine import database_url, make_engine
from nutribench.store.models import VIEWS, Base
from nutribench.store.schema import OPTUNA_TABLES, VERSION_TABLE

config = context.config
target_metadata = Base.metadata

if config.config_file_name is not None and config.attributes.get("connection") is None:
    logging.config.fileConfig(config.config_file_name, disable_existing_loggers=False)


def _url():
    x = context.get_x_argument(as_dictionary=True)
    if "db" in x:
        return database_url(x["db"])
    return database_url(config.get_main_option("sqlalchemy.url") or "nutribench.db")


def _include_object(obj, name, type_, reflected, compare_to):
    return not (type_ == "table" and (name in VIEWS or name in OPTUNA_TABLES))


def _configure(**kw) -> None:
    # nutribench's own version table: Optuna's storage, in the same database, uses alembic's
    # default ``alembic_version`` (nutribench.store.schema.VERSION_TABLE says why)
    context.configure(
        target_metadata=target_metadata,
        include_object=_include_object,
        compare_type=True,
        version_table=config.get_main_option("version_table") or VERSION_TABLE,
        **kw,
    )


def run_offline() -> None:
    url = _url()
    _configure(url=url, literal_binds=True, dialect_opts={"paramstyle": "named"})
    with context.begin_transaction():
        context.run_migrations()


def _run(connection) -> None:
    _configure(connection=connection, render_as_batch=connection.dialect.name == "sqlite")
    with context.begin_transaction():
        context.run_migrations()


def run_online() -> None:
    connection = config.attributes.get("connection")
    if connection is not None:
        _run(connection)
        return
    engine = make_engine(_url(), writer=True)
    try:
        with engine.connect() as conn:
            _run(conn)
            conn.commit()
    finally:
        engine.dispose()


if context.is_offline_mode():
    run_offline()
else:
    run_online()
