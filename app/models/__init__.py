"""SQLAlchemy 2.0 tables. Importing this package registers every table on ``Base.metadata``."""

from app.models.base import Base
from app.models.designs import EngineModel, EngineType, EstimatorDesign
from app.models.estimates import (
    DeteriorationBucket,
    EgtWindow,
    Estimate,
    EstimationBacklog,
    Event,
    EventComment,
    EventHistory,
    FilterCheckpoint,
    FilterState,
    FleetPeriod,
)
from app.models.fleet import Aircraft, Engine, Installation, MaintenanceAction
from app.models.ingest import Snapshot, StreamChunk, StreamRecording, Upload
from app.models.jobs import Job, JobSchedule
from app.models.notifications import (
    DeliveryAttempt,
    EngineAlertLevel,
    NotificationChannel,
    NotificationDelivery,
)
from app.models.stream_estimates import StreamEstimate, StreamFilterState
from app.models.tenancy import ApiKey, Operator

__all__ = [
    "Aircraft",
    "ApiKey",
    "Base",
    "DeliveryAttempt",
    "DeteriorationBucket",
    "Engine",
    "EngineAlertLevel",
    "EngineModel",
    "EngineType",
    "Estimate",
    "EstimationBacklog",
    "EstimatorDesign",
    "Event",
    "EventComment",
    "EventHistory",
    "FilterCheckpoint",
    "FilterState",
    "EgtWindow",
    "FleetPeriod",
    "Installation",
    "Job",
    "JobSchedule",
    "MaintenanceAction",
    "NotificationChannel",
    "NotificationDelivery",
    "Operator",
    "Snapshot",
    "StreamChunk",
    "StreamEstimate",
    "StreamFilterState",
    "StreamRecording",
    "Upload",
]
