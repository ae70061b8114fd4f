"""REST API v1 routes: thin, each delegating to ``server.services``."""
