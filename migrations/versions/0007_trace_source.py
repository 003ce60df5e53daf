"""trace source and circuit imports (file, layer, net, width; pads and areas)

Revision ID: 0007
Revises: 0003
"""

import sqlalchemy as sa
import sqlmodel.sql.sqltypes
from alembic import op

revision = '0007'
down_revision = '0003'
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table('traces') as batch:
        batch.add_column(sa.Column('source', sa.JSON(), nullable=True))
    op.create_table('circuit_imports',
    sa.Column('id', sqlmodel.sql.sqltypes.AutoString(length=40), nullable=False),
    sa.Column('part_id', sqlmodel.sql.sqltypes.AutoString(length=40), nullable=False),
    sa.Column('files', sa.JSON(), nullable=False),
    sa.Column('options', sa.JSON(), nullable=False),
    sa.Column('trace_ids', sa.JSON(), nullable=False),
    sa.Column('pads', sa.JSON(), nullable=False),
    sa.Column('areas', sa.JSON(), nullable=False),
    sa.Column('created_at', sa.DateTime(timezone=True), nullable=False),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_circuit_imports'))
    )
    with op.batch_alter_table('circuit_imports') as batch:
        batch.create_index(batch.f('ix_circuit_imports_part_id'), ['part_id'], unique=False)


def downgrade() -> None:
    with op.batch_alter_table('circuit_imports') as batch:
        batch.drop_index(batch.f('ix_circuit_imports_part_id'))
    op.drop_table('circuit_imports')
    with op.batch_alter_table('traces') as batch:
        batch.drop_column('source')
