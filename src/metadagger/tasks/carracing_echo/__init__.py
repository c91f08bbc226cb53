"""CarRacing whose frame echoes the steering just executed (docs/carracing-echo.md)."""
