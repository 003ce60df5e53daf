"""machine safety: one active machine job per machine, program state, unique ports

Revision ID: 0004
Revises: 0003
Create Date: 2026-11-25 01:10:00
"""

import sqlalchemy as sa
import sqlmodel.sql.sqltypes
from alembic import op

revision = '0004'
down_revision = '0005'
branch_labels = None
depends_on = None

_HOLDING = "machine_id IS NOT NULL AND status IN ('queued', 'running', 'interrupted')"


def upgrade() -> None:
    with op.batch_alter_table('jobs', schema=None) as batch_op:
        batch_op.add_column(sa.Column('machine_id', sqlmodel.sql.sqltypes.AutoString(length=40), nullable=True))
        batch_op.add_column(sa.Column('program_state', sa.JSON(), nullable=True))
    with op.batch_alter_table('machines', schema=None) as batch_op:
        batch_op.add_column(sa.Column('port_key', sqlmodel.sql.sqltypes.AutoString(length=500), nullable=True))
    # existing records: their port as given (mock ports are per record); a duplicate
    # keeps its row but gets a key of its own (it cannot be created any more)
    conn = op.get_bind()
    seen: set[str] = set()
    for machine_id, port in conn.execute(sa.text("SELECT id, port FROM machines ORDER BY created_at")).all():
        key = f"mock:{machine_id}" if port.startswith("mock://") else port
        if key in seen:
            key = f"{port}#duplicate:{machine_id}"
        seen.add(key)
        conn.execute(sa.text("UPDATE machines SET port_key = :key WHERE id = :id"), {"key": key, "id": machine_id})
    with op.batch_alter_table('machines', schema=None) as batch_op:
        batch_op.create_unique_constraint(batch_op.f('uq_machines_port_key'), ['port_key'])
    # jobs already holding a machine get its id (the oldest one per machine, should a
    # past race have let two in: the other keeps running unguarded until it ends)
    held: set[str] = set()
    rows = conn.execute(sa.text(
        "SELECT j.id, r.ref_id FROM jobs j JOIN job_references r ON r.job_id = j.id AND r.ref_kind = 'machine' "
        "WHERE j.kind IN ('print', 'probe_run', 'register') AND j.status IN ('queued', 'running') "
        "ORDER BY j.created_at")).all()
    for job_id, machine_id in rows:
        if machine_id not in held:
            held.add(machine_id)
            conn.execute(sa.text("UPDATE jobs SET machine_id = :m WHERE id = :id"), {"m": machine_id, "id": job_id})
    op.create_index('uq_jobs_active_machine', 'jobs', ['machine_id'], unique=True,
                    sqlite_where=sa.text(_HOLDING), postgresql_where=sa.text(_HOLDING))


def downgrade() -> None:
    op.drop_index('uq_jobs_active_machine', table_name='jobs')
    with op.batch_alter_table('machines', schema=None) as batch_op:
        batch_op.drop_constraint(batch_op.f('uq_machines_port_key'), type_='unique')
        batch_op.drop_column('port_key')
    with op.batch_alter_table('jobs', schema=None) as batch_op:
        batch_op.drop_column('program_state')
        batch_op.drop_column('machine_id')
