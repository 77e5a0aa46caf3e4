"""Lost-in-space star identification: pattern database, 4-star hashing search, verification."""

from skyfix.identify.database import PatternDatabase, default_database, default_database_path
from skyfix.identify.quad import Identification, identify

__all__ = ["Identification", "PatternDatabase", "default_database", "default_database_path", "identify"]
