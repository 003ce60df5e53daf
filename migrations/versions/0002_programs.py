"""programs

Revision ID: 0002
Revises: 0001
Create Date: 2026-11-21 11:59:09.562739
"""

import sqlalchemy as sa
import sqlmodel.sql.sqltypes
from alembic import op

revision = '0002'
down_revision = '0001'
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table('programs',
    sa.Column('id', sqlmodel.sql.sqltypes.AutoString(length=40), nullable=False),
    sa.Column('name', sqlmodel.sql.sqltypes.AutoString(length=200), nullable=False),
    sa.Column('sha256', sqlmodel.sql.sqltypes.AutoString(length=64), nullable=False),
    sa.Column('lines', sa.Integer(), nullable=False),
    sa.Column('commands', sa.Integer(), nullable=False),
    sa.Column('commands_sha256', sqlmodel.sql.sqltypes.AutoString(length=64), nullable=False),
    sa.Column('bounds', sa.JSON(), nullable=True),
    sa.Column('created_at', sa.DateTime(timezone=True), nullable=False),
    sa.ForeignKeyConstraint(['sha256'], ['blobs.sha256'], name=op.f('fk_programs_sha256_blobs')),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_programs'))
    )


def downgrade() -> None:
    op.drop_table('programs')
