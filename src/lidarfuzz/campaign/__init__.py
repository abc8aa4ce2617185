"""Campaigns: what a user asks lidarfuzz to run (the engine that runs them is being built)."""

from lidarfuzz.campaign.spec import CampaignSpec, OperatorChoice, load_campaign, parse_campaign

__all__ = ["CampaignSpec", "OperatorChoice", "load_campaign", "parse_campaign"]
