"""The one rate-limited logger, as the supervision objects use it: it lives in
:mod:`cr_control.core.rate_limited_log`, below the control laws, so that they use the same
one."""

from cr_control.core.rate_limited_log import PERIOD_S, Emit, RateLimitedLog, Text, logger_emit

__all__ = ["PERIOD_S", "Emit", "RateLimitedLog", "Text", "logger_emit"]
