"""Small environments written from scratch to show `env.factory` (docs/OWN_ENVIRONMENT.md)."""
