"""Load a recording from any file the tools accept, chosen by what the path is."""

from motor_id.recording import read_csv


def load_recording(path):
    """Read a recording from a CSV file or an MCAP bag.

    Parameters
    ----------
    path : str or os.PathLike
        ``*.mcap``: a bag with this project's ``/samples`` topic; anything else: CSV.

    Returns
    -------
    motor_id.recording.Recording
    """
    if str(path).endswith('.mcap'):
        from motor_id.bag import read_recording
        return read_recording(path)
    return read_csv(path)
