"""`accelcal serve` and the operator's browser front end: the line page, board and lot pages,
the operator page and the MES JSON API (FastAPI, uvicorn, Jinja2; scripts and styles served
from this package, nothing from a CDN).

It may import the store, the station flows, the lot report and the fixtures' operator
protocol; nothing below it imports it (only the CLI starts it).  It reads the store the
stations write and never writes it (the operator page drives a station through the
operator jig's protocol, and the station records as it always does).
"""
