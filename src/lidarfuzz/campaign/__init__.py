"""The campaign engine: campaign files (:mod:`~lidarfuzz.campaign.spec`), the table of task kinds
(:mod:`~lidarfuzz.campaign.kinds`), their shared lifecycle, and the kinds themselves.

Nothing is imported here, so that reading the table of kinds (``lidarfuzz run --help``) costs
no more than that module.
"""
