"""Operators: named people with their own bearer tokens, which expire and can be revoked at once."""
