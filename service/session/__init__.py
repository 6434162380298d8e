"""Session ingest: the `vysics-session/1` upload format (docs/session-ingest.md).

``ingest(source, dest)`` unpacks an upload safely into ``dest``, validates every rule and returns the typed
``Session``; ``load_session(root, sha256)`` re-reads a folder that ingest already validated;
``sha256_of(source)`` is the content hash of an upload. Bad input raises ``InvalidSession(file, rule)``.
"""

from service.errors import InvalidSession
from service.session.ingest import ingest, load_session, sha256_of
from service.session.types import Friction, Session

__all__ = ["Friction", "InvalidSession", "Session", "ingest", "load_session", "sha256_of"]
