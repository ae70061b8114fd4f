"""What the API shares: the typed dependencies and the server's own routes (health, whoami)."""
