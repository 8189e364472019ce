"""three_stage"""
