"""indirect"""
