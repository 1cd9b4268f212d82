function magnet_connect_error(url, err)
%MAGNET_CONNECT_ERROR Raise what webread/webwrite threw in one sentence naming the server's address:
%   magnet:connect when the server cannot be reached (refused, unknown host, timeout), magnet:http
%   for an error answer that carried no body. Errors of the wrapper itself (magnet:*) pass through.
  if strncmp(err.identifier, 'magnet:', 7)
    rethrow(err);
  end
  server = regexp(url, '^[A-Za-z][A-Za-z0-9+.-]*://[^/?#]+', 'match', 'once');
  if isempty(server)
    server = url;
  end
  why = regexprep(err.message, '^[A-Za-z_]+: *', '');  % Octave's '__restful_service__: ' prefix
  why = regexprep(why, '[.\s]+$', '');
  if ~isempty(why)
    why(1) = lower(why(1));
  end
  if ~isempty(regexpi(why, 'response code said error|HTTP [45]\d\d', 'once'))
    error('magnet:http', 'the MAGNET server at %s answered with an error (%s)', server, why);
  end
  error('magnet:connect', 'cannot reach the MAGNET server at %s (%s): is it running, and is the address right?', ...
        server, why);
end
