"""One error type for the server's services: an HTTP status and a message that names what is wrong."""

from __future__ import annotations

__all__ = ["ServiceError"]


class ServiceError(Exception):
    """Raised by the service layer; the app turns it into ``{"detail": message}`` with ``status``."""

    def __init__(self, status: int, message: str) -> None:
        super().__init__(message)
        self.status = status
        self.message = message
