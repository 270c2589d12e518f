"""The first schema of the process record: run, work_order, operation, part_unit, material_lot,
job_response, measurement, alarm, robot_move, job_state (see :mod:`factory.record`).

Revision ID: 0001
Revises:
Create Date: 2026-11-25
"""

from alembic import op
import sqlalchemy as sa

revision = "0001"
down_revision = None
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table('run',
    sa.Column('id', sa.Integer(), autoincrement=True, nullable=False),
    sa.Column('cell', sa.String(length=200), nullable=False),
    sa.Column('started_at', sa.DateTime(timezone=True), nullable=False),
    sa.Column('ended_at', sa.DateTime(timezone=True), nullable=True),
    sa.Column('factory_version', sa.String(length=40), nullable=False),
    sa.Column('orders_file', sa.Text(), nullable=False),
    sa.Column('orders_sha256', sa.String(length=64), nullable=False),
    sa.Column('faults_seed', sa.Integer(), nullable=True),
    sa.Column('makespan_s', sa.Float(), nullable=True),
    sa.Column('summary', sa.JSON(), nullable=True),
    sa.PrimaryKeyConstraint('id')
    )
    op.create_table('work_order',
    sa.Column('id', sa.Integer(), autoincrement=True, nullable=False),
    sa.Column('run_id', sa.Integer(), nullable=False),
    sa.Column('order_ref', sa.String(length=40), nullable=False),
    sa.Column('part', sa.Text(), nullable=False),
    sa.Column('part_sha256', sa.String(length=64), nullable=True),
    sa.Column('material', sa.String(length=100), nullable=False),
    sa.Column('quantity', sa.Integer(), nullable=False),
    sa.Column('priority', sa.Integer(), nullable=False),
    sa.Column('outcome', sa.String(length=20), nullable=True),
    sa.Column('good', sa.Integer(), nullable=False),
    sa.Column('rejected', sa.Integer(), nullable=False),
    sa.Column('reason', sa.Text(), nullable=True),
    sa.Column('ended_s', sa.Float(), nullable=True),
    sa.ForeignKeyConstraint(['run_id'], ['run.id'], ),
    sa.PrimaryKeyConstraint('id'),
    sa.UniqueConstraint('run_id', 'order_ref')
    )
    with op.batch_alter_table('work_order', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_work_order_run_id'), ['run_id'], unique=False)

    op.create_table('operation',
    sa.Column('id', sa.Integer(), autoincrement=True, nullable=False),
    sa.Column('run_id', sa.Integer(), nullable=False),
    sa.Column('work_order_id', sa.Integer(), nullable=False),
    sa.Column('sequence', sa.Integer(), nullable=False),
    sa.Column('name', sa.String(length=40), nullable=False),
    sa.Column('program', sa.Text(), nullable=False),
    sa.Column('program_sha256', sa.String(length=64), nullable=False),
    sa.Column('planned_machining_s', sa.Float(), nullable=False),
    sa.Column('ideal_cycle_s', sa.Float(), nullable=False),
    sa.ForeignKeyConstraint(['run_id'], ['run.id'], ),
    sa.ForeignKeyConstraint(['work_order_id'], ['work_order.id'], ),
    sa.PrimaryKeyConstraint('id'),
    sa.UniqueConstraint('work_order_id', 'sequence')
    )
    with op.batch_alter_table('operation', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_operation_run_id'), ['run_id'], unique=False)
        batch_op.create_index(batch_op.f('ix_operation_work_order_id'), ['work_order_id'], unique=False)

    op.create_table('part_unit',
    sa.Column('id', sa.Integer(), autoincrement=True, nullable=False),
    sa.Column('run_id', sa.Integer(), nullable=False),
    sa.Column('serial', sa.String(length=40), nullable=False),
    sa.Column('work_order_id', sa.Integer(), nullable=False),
    sa.Column('job', sa.Integer(), nullable=False),
    sa.Column('started_s', sa.Float(), nullable=False),
    sa.Column('ended_s', sa.Float(), nullable=True),
    sa.Column('outcome', sa.String(length=20), nullable=True),
    sa.Column('seq', sa.Integer(), nullable=False),
    sa.ForeignKeyConstraint(['run_id'], ['run.id'], ),
    sa.ForeignKeyConstraint(['work_order_id'], ['work_order.id'], ),
    sa.PrimaryKeyConstraint('id'),
    sa.UniqueConstraint('serial')
    )
    with op.batch_alter_table('part_unit', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_part_unit_run_id'), ['run_id'], unique=False)
        batch_op.create_index(batch_op.f('ix_part_unit_work_order_id'), ['work_order_id'], unique=False)

    op.create_table('alarm',
    sa.Column('id', sa.Integer(), autoincrement=True, nullable=False),
    sa.Column('run_id', sa.Integer(), nullable=False),
    sa.Column('part_unit_id', sa.Integer(), nullable=False),
    sa.Column('kind', sa.String(length=40), nullable=False),
    sa.Column('severity', sa.Integer(), nullable=False),
    sa.Column('state', sa.String(length=20), nullable=False),
    sa.Column('message', sa.Text(), nullable=True),
    sa.Column('raised_s', sa.Float(), nullable=False),
    sa.Column('lost_s', sa.Float(), nullable=False),
    sa.Column('recovery', sa.String(length=40), nullable=True),
    sa.Column('recovery_message', sa.Text(), nullable=True),
    sa.Column('outcome', sa.String(length=20), nullable=True),
    sa.Column('cleared_s', sa.Float(), nullable=True),
    sa.Column('seq', sa.Integer(), nullable=False),
    sa.ForeignKeyConstraint(['part_unit_id'], ['part_unit.id'], ),
    sa.ForeignKeyConstraint(['run_id'], ['run.id'], ),
    sa.PrimaryKeyConstraint('id')
    )
    with op.batch_alter_table('alarm', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_alarm_part_unit_id'), ['part_unit_id'], unique=False)
        batch_op.create_index(batch_op.f('ix_alarm_run_id'), ['run_id'], unique=False)

    op.create_table('job_response',
    sa.Column('id', sa.Integer(), autoincrement=True, nullable=False),
    sa.Column('run_id', sa.Integer(), nullable=False),
    sa.Column('part_unit_id', sa.Integer(), nullable=False),
    sa.Column('operation_id', sa.Integer(), nullable=False),
    sa.Column('kind', sa.String(length=20), nullable=False),
    sa.Column('program_sha256', sa.String(length=64), nullable=True),
    sa.Column('start_s', sa.Float(), nullable=False),
    sa.Column('end_s', sa.Float(), nullable=False),
    sa.Column('machine_time_s', sa.Float(), nullable=False),
    sa.Column('fraction', sa.Float(), nullable=False),
    sa.Column('outcome', sa.String(length=40), nullable=False),
    sa.Column('seq', sa.Integer(), nullable=False),
    sa.ForeignKeyConstraint(['operation_id'], ['operation.id'], ),
    sa.ForeignKeyConstraint(['part_unit_id'], ['part_unit.id'], ),
    sa.ForeignKeyConstraint(['run_id'], ['run.id'], ),
    sa.PrimaryKeyConstraint('id')
    )
    with op.batch_alter_table('job_response', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_job_response_part_unit_id'), ['part_unit_id'], unique=False)
        batch_op.create_index(batch_op.f('ix_job_response_run_id'), ['run_id'], unique=False)

    op.create_table('job_state',
    sa.Column('id', sa.Integer(), autoincrement=True, nullable=False),
    sa.Column('run_id', sa.Integer(), nullable=False),
    sa.Column('part_unit_id', sa.Integer(), nullable=True),
    sa.Column('work_order_id', sa.Integer(), nullable=False),
    sa.Column('time_s', sa.Float(), nullable=False),
    sa.Column('state', sa.String(length=20), nullable=False),
    sa.Column('event', sa.String(length=40), nullable=False),
    sa.Column('message', sa.Text(), nullable=True),
    sa.Column('seq', sa.Integer(), nullable=False),
    sa.ForeignKeyConstraint(['part_unit_id'], ['part_unit.id'], ),
    sa.ForeignKeyConstraint(['run_id'], ['run.id'], ),
    sa.ForeignKeyConstraint(['work_order_id'], ['work_order.id'], ),
    sa.PrimaryKeyConstraint('id')
    )
    with op.batch_alter_table('job_state', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_job_state_part_unit_id'), ['part_unit_id'], unique=False)
        batch_op.create_index(batch_op.f('ix_job_state_run_id'), ['run_id'], unique=False)

    op.create_table('material_lot',
    sa.Column('id', sa.Integer(), autoincrement=True, nullable=False),
    sa.Column('run_id', sa.Integer(), nullable=False),
    sa.Column('lot', sa.String(length=40), nullable=False),
    sa.Column('rack_slot', sa.Integer(), nullable=False),
    sa.Column('material', sa.String(length=100), nullable=False),
    sa.Column('part_unit_id', sa.Integer(), nullable=False),
    sa.Column('taken_s', sa.Float(), nullable=False),
    sa.Column('seq', sa.Integer(), nullable=False),
    sa.ForeignKeyConstraint(['part_unit_id'], ['part_unit.id'], ),
    sa.ForeignKeyConstraint(['run_id'], ['run.id'], ),
    sa.PrimaryKeyConstraint('id'),
    sa.UniqueConstraint('lot')
    )
    with op.batch_alter_table('material_lot', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_material_lot_part_unit_id'), ['part_unit_id'], unique=False)
        batch_op.create_index(batch_op.f('ix_material_lot_run_id'), ['run_id'], unique=False)

    op.create_table('measurement',
    sa.Column('id', sa.Integer(), autoincrement=True, nullable=False),
    sa.Column('run_id', sa.Integer(), nullable=False),
    sa.Column('part_unit_id', sa.Integer(), nullable=False),
    sa.Column('characteristic', sa.String(length=80), nullable=False),
    sa.Column('unit', sa.String(length=10), nullable=False),
    sa.Column('nominal', sa.Float(), nullable=False),
    sa.Column('tolerance', sa.Float(), nullable=False),
    sa.Column('actual', sa.Float(), nullable=False),
    sa.Column('passed', sa.Boolean(), nullable=False),
    sa.Column('time_s', sa.Float(), nullable=False),
    sa.Column('seq', sa.Integer(), nullable=False),
    sa.ForeignKeyConstraint(['part_unit_id'], ['part_unit.id'], ),
    sa.ForeignKeyConstraint(['run_id'], ['run.id'], ),
    sa.PrimaryKeyConstraint('id')
    )
    with op.batch_alter_table('measurement', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_measurement_part_unit_id'), ['part_unit_id'], unique=False)
        batch_op.create_index(batch_op.f('ix_measurement_run_id'), ['run_id'], unique=False)

    op.create_table('robot_move',
    sa.Column('id', sa.Integer(), autoincrement=True, nullable=False),
    sa.Column('run_id', sa.Integer(), nullable=False),
    sa.Column('part_unit_id', sa.Integer(), nullable=False),
    sa.Column('action', sa.String(length=40), nullable=False),
    sa.Column('rack_slot', sa.Integer(), nullable=True),
    sa.Column('start_s', sa.Float(), nullable=False),
    sa.Column('end_s', sa.Float(), nullable=False),
    sa.Column('fraction', sa.Float(), nullable=False),
    sa.Column('outcome', sa.String(length=40), nullable=False),
    sa.Column('seq', sa.Integer(), nullable=False),
    sa.ForeignKeyConstraint(['part_unit_id'], ['part_unit.id'], ),
    sa.ForeignKeyConstraint(['run_id'], ['run.id'], ),
    sa.PrimaryKeyConstraint('id')
    )
    with op.batch_alter_table('robot_move', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_robot_move_part_unit_id'), ['part_unit_id'], unique=False)
        batch_op.create_index(batch_op.f('ix_robot_move_run_id'), ['run_id'], unique=False)


def downgrade() -> None:
    with op.batch_alter_table('robot_move', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_robot_move_run_id'))
        batch_op.drop_index(batch_op.f('ix_robot_move_part_unit_id'))

    op.drop_table('robot_move')
    with op.batch_alter_table('measurement', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_measurement_run_id'))
        batch_op.drop_index(batch_op.f('ix_measurement_part_unit_id'))

    op.drop_table('measurement')
    with op.batch_alter_table('material_lot', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_material_lot_run_id'))
        batch_op.drop_index(batch_op.f('ix_material_lot_part_unit_id'))

    op.drop_table('material_lot')
    with op.batch_alter_table('job_state', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_job_state_run_id'))
        batch_op.drop_index(batch_op.f('ix_job_state_part_unit_id'))

    op.drop_table('job_state')
    with op.batch_alter_table('job_response', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_job_response_run_id'))
        batch_op.drop_index(batch_op.f('ix_job_response_part_unit_id'))

    op.drop_table('job_response')
    with op.batch_alter_table('alarm', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_alarm_run_id'))
        batch_op.drop_index(batch_op.f('ix_alarm_part_unit_id'))

    op.drop_table('alarm')
    with op.batch_alter_table('part_unit', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_part_unit_work_order_id'))
        batch_op.drop_index(batch_op.f('ix_part_unit_run_id'))

    op.drop_table('part_unit')
    with op.batch_alter_table('operation', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_operation_work_order_id'))
        batch_op.drop_index(batch_op.f('ix_operation_run_id'))

    op.drop_table('operation')
    with op.batch_alter_table('work_order', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_work_order_run_id'))

    op.drop_table('work_order')
    op.drop_table('run')
