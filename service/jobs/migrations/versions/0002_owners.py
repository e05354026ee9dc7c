"""Owners: the user who submitted each job, and the users who sent each upload.

Jobs and uploads from before (or made while no token is set) have no owner: only an admin
(or everyone, on an open service) sees them.

Revision ID: 0002
Revises: 0001
Create Date: 2026-11-27
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0002"
down_revision = "0001"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("jobs") as batch:
        batch.add_column(sa.Column("owner", sa.String(64)))
    op.create_index("ix_jobs_owner", "jobs", ["owner"])
    op.create_table(
        "upload_owners",
        sa.Column(
            "upload_id",
            sa.String(36),
            sa.ForeignKey("uploads.id", ondelete="CASCADE"),
            primary_key=True,
        ),
        sa.Column("owner", sa.String(64), primary_key=True),
    )


def downgrade() -> None:
    op.drop_table("upload_owners")
    op.drop_index("ix_jobs_owner", "jobs")
    with op.batch_alter_table("jobs") as batch:
        batch.drop_column("owner")
