"""part intake frame: units, orientation, source file, warnings, mesh defects

Revision ID: 0006
Revises: 0003
"""

import sqlalchemy as sa
import sqlmodel.sql.sqltypes
from alembic import op

revision = '0006'
down_revision = '0007'
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table('parts', schema=None) as batch_op:
        batch_op.add_column(sa.Column('units', sqlmodel.sql.sqltypes.AutoString(length=8), nullable=False,
                                      server_default='mm'))
        batch_op.add_column(sa.Column('frame', sa.JSON(), nullable=True))
        batch_op.add_column(sa.Column('source_sha256', sqlmodel.sql.sqltypes.AutoString(length=64), nullable=True))
        batch_op.add_column(sa.Column('source_format', sqlmodel.sql.sqltypes.AutoString(length=10), nullable=True))
        batch_op.add_column(sa.Column('warnings', sa.JSON(), nullable=True))
        batch_op.add_column(sa.Column('defects', sa.JSON(), nullable=True))
        batch_op.create_foreign_key(batch_op.f('fk_parts_source_sha256_blobs'), 'blobs', ['source_sha256'],
                                    ['sha256'])


def downgrade() -> None:
    with op.batch_alter_table('parts', schema=None) as batch_op:
        batch_op.drop_constraint(batch_op.f('fk_parts_source_sha256_blobs'), type_='foreignkey')
        batch_op.drop_column('defects')
        batch_op.drop_column('warnings')
        batch_op.drop_column('source_format')
        batch_op.drop_column('source_sha256')
        batch_op.drop_column('frame')
        batch_op.drop_column('units')
