"""models/rules"""
