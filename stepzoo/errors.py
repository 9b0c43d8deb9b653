"""The exceptions a command turns into its exit status: UsageError, a mistake in the input
(one line, exit 2), and NoAnswer, a correct run that found no answer (one line, exit 1)."""


class UsageError(Exception):
    """A mistake in the user's input, with a message that says what to do."""


class NoAnswer(Exception):
    """The command ran correctly but found nothing that meets the request (exit status 1)."""
