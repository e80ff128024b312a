"""SQLAlchemy 2.0 tables. Importing this package registers every table on ``Base.metadata``."""

from app.models.base import Base
from app.models.tenancy import ApiKey, Operator

__all__ = ["ApiKey", "Base", "Operator"]
