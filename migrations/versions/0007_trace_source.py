"""trace source (circuit imports: file, layer, net, width)

Revision ID: 0007
Revises: 0003
"""

from alembic import op
import sqlalchemy as sa


revision = '0007'
down_revision = '0003'
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table('traces') as batch:
        batch.add_column(sa.Column('source', sa.JSON(), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table('traces') as batch:
        batch.drop_column('source')
