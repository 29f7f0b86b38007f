"""Reward functions: the task terms, the human intent terms, and (later) the assistant's reward."""

from d2a_core.objectives.rewards import INTENTS, RewardConfig, RewardTerms, StepQuantities, intent_reward, reward_terms, task_reward

__all__ = ["INTENTS", "RewardConfig", "RewardTerms", "StepQuantities", "intent_reward", "reward_terms", "task_reward"]
