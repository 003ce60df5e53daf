"""job state needs_attention: the status column takes up to 20 characters

SQLite does not enforce a VARCHAR's length (and a batch copy of the jobs table would have
to carry its partial unique index), so only other databases alter the column.

Revision ID: 0010
Revises: 0009
"""

import sqlmodel.sql.sqltypes
from alembic import op

revision = '0010'
down_revision = '0009'
branch_labels = None
depends_on = None


def _status(length: int, was: int) -> None:
    if op.get_bind().dialect.name == 'sqlite':
        return
    op.alter_column('jobs', 'status', existing_type=sqlmodel.sql.sqltypes.AutoString(length=was),
                    type_=sqlmodel.sql.sqltypes.AutoString(length=length), existing_nullable=False)


def upgrade() -> None:
    _status(20, 12)


def downgrade() -> None:
    op.execute("UPDATE jobs SET status = 'succeeded' WHERE status = 'needs_attention'")
    _status(12, 20)
