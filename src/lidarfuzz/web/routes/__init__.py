"""The API's routes, one module per resource: tasks, reports, findings, frames, datasets, models,
catalogue (operators, relations, previews, systems under test)."""
