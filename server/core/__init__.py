"""What every domain of the shore uses: settings, the database, errors mapped to HTTP, events, tokens."""
