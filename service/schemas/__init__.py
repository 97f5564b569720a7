"""Request and response schemas of the API, one module per domain: common (health,
worlds), qualitative, eigenspace, slam, viewpoint, jobs. Every route declares its
response model, so the OpenAPI document says what each answer holds."""
