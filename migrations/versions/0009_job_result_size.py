"""job result size and summary (a large result is not inlined in the job's record)

Revision ID: 0009
Revises: 0008
"""

import sqlalchemy as sa
from alembic import op

revision = '0009'
down_revision = '0008'
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table('jobs') as batch:
        batch.add_column(sa.Column('result_bytes', sa.Integer(), nullable=True))
        batch.add_column(sa.Column('result_summary', sa.JSON(), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table('jobs') as batch:
        batch.drop_column('result_summary')
        batch.drop_column('result_bytes')
