"""The HTTP API's routers: uploads, processes and jobs (under ``/v1``), health, pages."""
