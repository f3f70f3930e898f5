"""mujoco"""
