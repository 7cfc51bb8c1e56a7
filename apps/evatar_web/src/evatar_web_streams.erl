%% @doc Internal. Admits the server-sent event streams of `GET /api/events'
%% (evatar_web_events): at most half of the server's `max_clients' at once (32
%% by default), so open streams never take every connection from the API.
%% Each admitted stream's process is monitored: its slot is free again when
%% it ends, however it ends.
-module(evatar_web_streams).
-behaviour(gen_server).

-export([start_link/0, admit/0, release/0, count/0, max/0]).
-export([init/1, handle_call/3, handle_cast/2, handle_info/2]).

%% @doc Started by evatar_web_sup before the HTTP server.
-spec start_link() -> {ok, pid()} | {error, term()}.
start_link() ->
    gen_server:start_link({local, ?MODULE}, ?MODULE, [], []).

%% @doc Takes a slot for the calling process, or says the limit is reached.
-spec admit() -> ok | {error, too_many_streams}.
admit() ->
    gen_server:call(?MODULE, {admit, self()}).

%% @doc Gives the calling process's slot back (its end does it too).
-spec release() -> ok.
release() ->
    gen_server:call(?MODULE, {release, self()}).

%% @doc The streams open now.
-spec count() -> non_neg_integer().
count() ->
    gen_server:call(?MODULE, count).

%% @doc The most streams open at once.
-spec max() -> pos_integer().
max() ->
    max(1, application:get_env(evatar_web, max_clients, 64) div 2).

%% @private
-spec init([]) -> {ok, #{reference() => pid()}}.
init([]) ->
    {ok, #{}}.

%% @private
-spec handle_call(term(), gen_server:from(), #{reference() => pid()}) ->
          {reply, term(), #{reference() => pid()}}.
handle_call({admit, Pid}, _From, Streams) ->
    case map_size(Streams) < max() of
        true -> {reply, ok, Streams#{erlang:monitor(process, Pid) => Pid}};
        false -> {reply, {error, too_many_streams}, Streams}
    end;
handle_call({release, Pid}, _From, Streams) ->
    Mine = [Ref || {Ref, P} <- maps:to_list(Streams), P =:= Pid],
    _ = [erlang:demonitor(Ref, [flush]) || Ref <- Mine],
    {reply, ok, maps:without(Mine, Streams)};
handle_call(count, _From, Streams) ->
    {reply, map_size(Streams), Streams}.

%% @private
-spec handle_cast(term(), #{reference() => pid()}) -> {noreply, #{reference() => pid()}}.
handle_cast(_Msg, Streams) ->
    {noreply, Streams}.

%% @private
-spec handle_info(term(), #{reference() => pid()}) -> {noreply, #{reference() => pid()}}.
handle_info({'DOWN', Ref, process, _, _}, Streams) ->
    {noreply, maps:remove(Ref, Streams)};
handle_info(_Msg, Streams) ->
    {noreply, Streams}.
