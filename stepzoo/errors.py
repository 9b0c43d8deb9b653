"""The user-mistake exception: the command prints its one-line message and exits with 2."""


class UsageError(Exception):
    """A mistake in the user's input, with a message that says what to do."""
