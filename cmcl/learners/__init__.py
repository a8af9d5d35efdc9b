"""Learners (torch): stacked nets, MADDPG, K-fold teachers, ICM, weight publication, the numpy rollout policy."""
