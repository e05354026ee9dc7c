"""The job store's first schema: uploads, jobs, job inputs, workers, counters.

Revision ID: 0001
Revises:
Create Date: 2026-11-24
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0001"
down_revision = None
branch_labels = None
depends_on = None

DOUBLE = sa.Float(53)


def upgrade() -> None:
    op.create_table(
        "uploads",
        sa.Column("id", sa.String(36), primary_key=True),
        sa.Column("sha256", sa.String(64), nullable=False, unique=True),
        sa.Column("filename", sa.String(255), nullable=False),
        sa.Column("format", sa.String(16), nullable=False),
        sa.Column("kind", sa.String(8), nullable=False),
        sa.Column("size_bytes", sa.BigInteger, nullable=False),
        sa.Column("n_points", sa.BigInteger),
        sa.Column("n_triangles", sa.BigInteger),
        sa.Column("info", sa.JSON, nullable=False),
        sa.Column("path", sa.String(512), nullable=False),
        sa.Column("created", DOUBLE, nullable=False),
    )
    op.create_table(
        "jobs",
        sa.Column("id", sa.String(36), primary_key=True),
        sa.Column("process", sa.String(32), nullable=False),
        sa.Column("status", sa.String(16), nullable=False),
        sa.Column("inputs", sa.JSON, nullable=False),
        sa.Column("parameters", sa.JSON, nullable=False),
        sa.Column("progress", DOUBLE, nullable=False),
        sa.Column("stage", sa.String(200)),
        sa.Column("message", sa.Text),
        sa.Column("error", sa.JSON),
        sa.Column("attempt", sa.Integer, nullable=False),
        sa.Column("max_attempts", sa.Integer, nullable=False),
        sa.Column("time_limit_s", DOUBLE, nullable=False),
        sa.Column("worker_id", sa.String(200)),
        sa.Column("lease_expires", DOUBLE),
        sa.Column("created", DOUBLE, nullable=False),
        sa.Column("started", DOUBLE),
        sa.Column("finished", DOUBLE),
        sa.Column("updated", DOUBLE, nullable=False),
        sa.Column("results", sa.JSON),
        sa.Column("summary", sa.JSON),
    )
    op.create_index("ix_jobs_status_created", "jobs", ["status", "created"])
    op.create_index("ix_jobs_created", "jobs", ["created", "id"])
    op.create_table(
        "job_inputs",
        sa.Column(
            "job_id",
            sa.String(36),
            sa.ForeignKey("jobs.id", ondelete="CASCADE"),
            primary_key=True,
        ),
        sa.Column("name", sa.String(64), primary_key=True),
        sa.Column("upload_id", sa.String(36)),
        sa.Column("source_job_id", sa.String(36)),
    )
    op.create_index("ix_job_inputs_upload_id", "job_inputs", ["upload_id"])
    op.create_index("ix_job_inputs_source_job_id", "job_inputs", ["source_job_id"])
    op.create_table(
        "workers",
        sa.Column("id", sa.String(200), primary_key=True),
        sa.Column("hostname", sa.String(255), nullable=False),
        sa.Column("pid", sa.Integer, nullable=False),
        sa.Column("executor", sa.String(16), nullable=False),
        sa.Column("slots", sa.Integer, nullable=False),
        sa.Column("started", DOUBLE, nullable=False),
        sa.Column("heartbeat", DOUBLE, nullable=False),
        sa.Column("stopped", DOUBLE),
    )
    op.create_table(
        "counters",
        sa.Column("name", sa.String(64), primary_key=True),
        sa.Column("label", sa.String(64), primary_key=True),
        sa.Column("count", sa.BigInteger, nullable=False),
        sa.Column("total", DOUBLE, nullable=False),
    )


def downgrade() -> None:
    for table in ("counters", "workers", "job_inputs", "jobs", "uploads"):
        op.drop_table(table)
